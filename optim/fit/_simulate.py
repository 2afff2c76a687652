"""Simulated calibration sessions against a simulated observer with known CSF constants.

[LH01 §6.1] calibrates a per-user CSF: the user fixates a target while a
grating *fades in*, slowly increasing in contrast, and presses a button when something becomes visible
(then clicks on the grating to verify). ``fade_in_session`` simulates this method of adjustment;
``staircase_2afc`` simulates the usual alternative, a two-alternative forced-choice (2AFC) staircase.
Both run against a :class:`SimulatedObserver` whose true threshold is a CSF model's, to test how well a
procedure (and a later fit) recovers known constants. Both are vectorized over stimuli (numpy; one
random generator seeded by the observer's seed, so sessions are reproducible) and return a
:class:`optim.fit.CalibrationData`.

Psychometric function (log-normal, i.e. a cumulative normal in log10 contrast)::

    P_core(c) = Phi(slope * log10(c / c_T)),   c_T = 1 / model.stimulus_sensitivity(f, e, v, L, A)
    P(c)      = guess + (1 - guess - lapse) * P_core(c)

so c_T is the 50 % point of the core function (the threshold definition of [Bar99]) and the contrast at
which an observer first detects a fading-in grating is log-normal with median c_T and a standard
deviation of ``1 / slope`` log10 units. ``slope = inf`` is a noise-free (step) observer.
Units: f cycles/deg, e deg, v deg/s, luminance cd/m2, area deg2, contrast Michelson.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.special import ndtr, ndtri

from pmetric import PlodError
from pmetric._base import check_broadcast

from ._data import CalibrationData

__all__ = ["SimulatedObserver", "Stimuli", "stimulus_grid", "fade_in_session", "staircase_2afc", "RULES"]

#: staircase rules: name -> (number of consecutive correct answers before a step down, convergence P)
RULES = {
    "1down1up": (1, 0.5),
    "2down1up": (2, 0.5 ** (1 / 2)),
    "3down1up": (3, 0.5 ** (1 / 3)),
    "4down1up": (4, 0.5 ** (1 / 4)),
}


@dataclasses.dataclass(frozen=True)
class Stimuli:
    """Calibration stimuli: 1-D float arrays of equal length (numpy).

    ``f`` cycles/deg (> 0), ``e`` deg, ``v`` retinal velocity deg/s, ``luminance`` cd/m2 and ``area`` deg2
    (NaN = the model's default).
    """

    f: np.ndarray
    e: np.ndarray
    v: np.ndarray
    luminance: np.ndarray
    area: np.ndarray

    def __post_init__(self):
        arrs = {k: np.asarray(getattr(self, k), dtype=np.float64) for k in ("f", "e", "v", "luminance", "area")}
        shape = check_broadcast("Stimuli", **{k: a.shape for k, a in arrs.items()})
        if len(shape) > 1:
            raise PlodError(f"Stimuli: arrays must be scalars or 1-D, broadcast shape is {shape}")
        for k, a in arrs.items():
            a = np.broadcast_to(a, shape).reshape(-1).copy()
            if k in ("f", "e", "v") and not np.isfinite(a).all():
                raise PlodError(f"Stimuli: {k} must be finite")
            bad = a <= 0 if k == "f" else a < 0
            if np.any(bad & ~np.isnan(a)):
                raise PlodError(f"Stimuli: {k} must be {'> 0' if k == 'f' else '>= 0'}, got {a[bad][0]!r}")
            a.setflags(write=False)
            object.__setattr__(self, k, a)

    def __len__(self) -> int:
        return self.f.shape[0]


def stimulus_grid(freqs, eccs=(0.0,), vels=(0.0,), luminance=np.nan, area=np.nan) -> Stimuli:
    """Every combination of ``freqs`` (cycles/deg) x ``eccs`` (deg) x ``vels`` (deg/s), frequency fastest."""
    vv, ee, ff = np.meshgrid(np.asarray(vels, float), np.asarray(eccs, float), np.asarray(freqs, float),
                             indexing="ij")
    return Stimuli(ff.ravel(), ee.ravel(), vv.ravel(), luminance, area)


class SimulatedObserver:
    """An observer whose threshold contrast is ``1 / model.stimulus_sensitivity`` (see module doc).

    Parameters: ``model`` a ``pmetric.CSFModel``; ``slope`` of the log-normal psychometric function
    (per log10 unit of contrast; ``inf`` = noise-free); ``lapse`` rate in [0, 1) (the observer answers
    at random / presses the button at a random moment); ``guess`` the guess rate of the core task
    (0 for yes/no detection; 2AFC uses max(guess, 0.5)); ``seed`` of ``numpy.random.default_rng``.
    """

    def __init__(self, model, slope: float = 4.0, lapse: float = 0.0, guess: float = 0.0, seed: int = 0):
        if not hasattr(model, "stimulus_sensitivity"):
            raise PlodError(f"SimulatedObserver: model must be a pmetric CSF model, got {type(model).__name__}")
        if not (slope > 0) or math.isnan(slope):
            raise PlodError(f"SimulatedObserver: slope must be > 0 (inf = noise-free), got {slope!r}")
        if not (0.0 <= lapse < 1.0):
            raise PlodError(f"SimulatedObserver: lapse must be in [0, 1), got {lapse!r}")
        if not (0.0 <= guess < 1.0) or guess + lapse >= 1.0:
            raise PlodError(f"SimulatedObserver: guess must be in [0, 1) with guess + lapse < 1, got {guess!r}")
        self.model = model
        self.slope = float(slope)
        self.lapse = float(lapse)
        self.guess = float(guess)
        self.seed = int(seed)
        self.rng = np.random.default_rng(seed)

    def threshold(self, stimuli: Stimuli) -> np.ndarray:
        """The true threshold contrast c_T (the model's) of each stimulus, float64 (n,)."""
        s = self.model.stimulus_sensitivity(stimuli.f, stimuli.e, stimuli.v, stimuli.luminance, stimuli.area)
        return 1.0 / np.asarray(s, dtype=np.float64).reshape(-1)

    def p_core(self, c, c_t) -> np.ndarray:
        """Core probability of detecting contrast ``c`` with threshold ``c_t`` (no guessing, no lapses)."""
        z = np.log10(np.maximum(c, 1e-300)) - np.log10(c_t)
        if math.isinf(self.slope):
            return (z >= 0).astype(np.float64)
        return ndtr(self.slope * z)

    def p_correct(self, c, c_t, guess: float | None = None) -> np.ndarray:
        """P(c) = guess + (1 - guess - lapse) P_core(c)."""
        g = self.guess if guess is None else guess
        return g + (1.0 - g - self.lapse) * self.p_core(c, c_t)

    def contrast_at(self, p, c_t, guess: float | None = None) -> np.ndarray:
        """Inverse psychometric function: the contrast at which P(c) = p (NaN where p is out of range)."""
        g = self.guess if guess is None else guess
        q = (np.asarray(p, float) - g) / (1.0 - g - self.lapse)
        with np.errstate(invalid="ignore", divide="ignore"):
            z = ndtri(np.where((q > 0) & (q < 1), q, np.nan))
        if math.isinf(self.slope):
            z = np.where(np.isnan(z), np.nan, 0.0)
            return np.asarray(c_t) * 10.0 ** z
        return np.asarray(c_t) * 10.0 ** (z / self.slope)

    def detection_contrast(self, c_t) -> np.ndarray:
        """Draw, for each threshold, the contrast at which a rising grating is first detected."""
        c_t = np.asarray(c_t, float)
        if math.isinf(self.slope):
            return c_t.copy()
        return c_t * 10.0 ** (self.rng.standard_normal(c_t.shape) / self.slope)


def _labels(observer, method):
    return dict(dataset=f"simulated_{method}", observer=f"sim{observer.seed}", stimulus=method,
                source=f"optim.fit.simulate {type(observer.model).__name__} slope={observer.slope:g} "
                       f"lapse={observer.lapse:g} seed={observer.seed}")


def fade_in_session(
    observer: SimulatedObserver,
    stimuli: Stimuli,
    rate_db_per_s: float = 6.0,
    reaction_time_s: float = 0.4,
    *,
    reaction_sd_s: float = 0.0,
    start_contrast: float = 1e-3,
    max_contrast: float = 1.0,
    frame_rate: float | None = None,
    positions: int = 4,
) -> CalibrationData:
    """The method of adjustment of [LH01 §6.1]: the grating's contrast rises from ``start_contrast``
    by ``rate_db_per_s`` (dB of contrast, 20 log10, per second) until the observer presses a button.

    The observer detects the grating at ``observer.detection_contrast`` (or, with probability
    ``lapse``, presses at a random moment of the ramp) and responds after a reaction time drawn from
    N(``reaction_time_s``, ``reaction_sd_s``) (s, clipped at 0). With ``frame_rate`` (Hz) the display
    changes contrast once per frame (detection at the first frame at or above the detection contrast);
    otherwise the ramp is continuous. The recorded threshold is the contrast on screen at the response
    corrected for the nominal reaction time: c_resp / 10^(rate * reaction_time_s / 20).

    The verification click of [LH01 §6.1] is simulated: a genuine detection clicks the right one of
    ``positions`` grating positions; a lapse clicks at random, and rows with a wrong click are dropped,
    as are gratings never detected up to ``max_contrast`` and those detected at the ramp's start (a
    threshold at or below ``start_contrast``, which the ramp cannot measure). Returns ``CalibrationData`` (dataset
    ``simulated_fade``) with the stimuli that remain.
    """
    if not (rate_db_per_s > 0 and math.isfinite(rate_db_per_s)):
        raise PlodError(f"fade_in_session: rate_db_per_s must be a positive number, got {rate_db_per_s!r}")
    if not (reaction_time_s >= 0 and reaction_sd_s >= 0):
        raise PlodError("fade_in_session: reaction_time_s and reaction_sd_s must be >= 0")
    if not (0 < start_contrast < max_contrast <= 1.0):
        raise PlodError("fade_in_session: need 0 < start_contrast < max_contrast <= 1")
    if frame_rate is not None and not frame_rate > 0:
        raise PlodError(f"fade_in_session: frame_rate must be > 0 Hz, got {frame_rate!r}")
    if int(positions) < 1:
        raise PlodError("fade_in_session: positions must be >= 1")
    rng = observer.rng
    n = len(stimuli)
    c_t = observer.threshold(stimuli)
    k = rate_db_per_s / 20.0  # log10 contrast per second
    t_end = (math.log10(max_contrast) - math.log10(start_contrast)) / k

    c_det = observer.detection_contrast(c_t)
    t_det = np.maximum(np.log10(c_det) - math.log10(start_contrast), 0.0) / k
    if frame_rate is not None:
        t_det = np.ceil(t_det * frame_rate - 1e-9) / frame_rate
    lapse = rng.random(n) < observer.lapse
    t_det = np.where(lapse, rng.random(n) * t_end, t_det)
    rt = reaction_time_s + (reaction_sd_s * rng.standard_normal(n) if reaction_sd_s > 0 else 0.0)
    t_resp = t_det + np.maximum(rt, 0.0)
    seen = t_det <= t_end
    # a grating seen as the ramp starts (threshold at or below start_contrast) measures nothing: its
    # response would record the start contrast, not a threshold (a censored row)
    censored = ~lapse & (np.log10(c_det) <= math.log10(start_contrast))
    verified = ~lapse | (rng.integers(0, int(positions), n) == 0)
    keep = seen & verified & ~censored
    if frame_rate is not None:
        t_shown = np.floor(t_resp * frame_rate + 1e-9) / frame_rate
    else:
        t_shown = t_resp
    log_c_resp = math.log10(start_contrast) + k * np.minimum(t_shown, t_end + reaction_time_s)
    log_thr = log_c_resp - k * reaction_time_s
    return CalibrationData.from_arrays(
        stimuli.f[keep], log_thr[keep], e=stimuli.e[keep], velocity=stimuli.v[keep],
        luminance=stimuli.luminance[keep], area=stimuli.area[keep], **_labels(observer, "fade"),
    )


def staircase_2afc(
    observer: SimulatedObserver,
    stimuli: Stimuli,
    rule: str = "3down1up",
    trials: int = 80,
    *,
    start_contrast: float = 0.5,
    step_db: float = 2.0,
    max_contrast: float = 1.0,
    discard_reversals: int = 4,
    fast_start: bool = True,
) -> CalibrationData:
    """A 2AFC staircase per stimulus, all stimuli in parallel.

    Each trial shows the grating in one of two intervals; the observer is correct with probability
    ``observer.p_correct(c, c_T, guess=max(observer.guess, 0.5))``. ``rule`` "Ndown1up" lowers the
    contrast by ``step_db`` (dB, 20 log10) after N consecutive correct answers and raises it after each
    error (capped at ``max_contrast``); it converges to P = 0.5^(1/N) correct (3down1up: 79.4 %).
    With ``fast_start`` (the rapid initial descent of [Lev71]) the track steps down after every correct
    answer by twice ``step_db`` until its first reversal.
    The threshold is the geometric mean of the contrasts at the reversals after the first
    ``discard_reversals`` (all reversals if there are not more). Rows whose staircase sat at
    ``max_contrast`` for the whole second half, whose estimate lies within 1.5 steps of ``max_contrast``
    (invisible gratings) or that never reversed are dropped.
    Returns ``CalibrationData`` (dataset ``simulated_2afc``).
    """
    if rule not in RULES:
        raise PlodError(f"staircase_2afc: unknown rule {rule!r}; choose one of {sorted(RULES)}")
    if int(trials) < 2:
        raise PlodError(f"staircase_2afc: trials must be >= 2, got {trials!r}")
    if not (step_db > 0 and math.isfinite(step_db)):
        raise PlodError(f"staircase_2afc: step_db must be a positive number, got {step_db!r}")
    if not (0 < start_contrast <= max_contrast <= 1.0):
        raise PlodError("staircase_2afc: need 0 < start_contrast <= max_contrast <= 1")
    if discard_reversals < 0:
        raise PlodError("staircase_2afc: discard_reversals must be >= 0")
    n_down = RULES[rule][0]
    rng = observer.rng
    n = len(stimuli)
    c_t = observer.threshold(stimuli)
    guess = max(observer.guess, 0.5)
    step = step_db / 20.0
    log_max = math.log10(max_contrast)
    log_c = np.full(n, math.log10(start_contrast))
    run = np.zeros(n, dtype=np.int64)
    last_dir = np.zeros(n, dtype=np.int64)  # +1 up, -1 down, 0 none yet
    rev_sum = np.zeros(n)
    rev_sum_all = np.zeros(n)
    rev_count = np.zeros(n, dtype=np.int64)
    at_max = np.zeros(n, dtype=np.int64)
    half = int(trials) // 2
    for t in range(int(trials)):
        correct = rng.random(n) < observer.p_correct(10.0**log_c, c_t, guess=guess)
        run = np.where(correct, run + 1, 0)
        fast = fast_start & (rev_count == 0)
        down = correct & ((run >= n_down) | fast)
        up = ~correct
        direction = np.where(down, -1, np.where(up, 1, 0))
        reversal = (direction != 0) & (last_dir != 0) & (direction != last_dir)
        rev_count += reversal
        rev_sum_all += np.where(reversal, log_c, 0.0)
        rev_sum += np.where(reversal & (rev_count > discard_reversals), log_c, 0.0)
        last_dir = np.where(direction != 0, direction, last_dir)
        run = np.where(down, 0, run)
        size = np.where(fast, 2.0 * step, step)
        log_c = np.clip(log_c - size * down + size * up, None, log_max)
        if t >= half:
            at_max += log_c >= log_max
    used = rev_count - discard_reversals
    est = np.where(used > 0, rev_sum / np.maximum(used, 1), rev_sum_all / np.maximum(rev_count, 1))
    keep = (rev_count > 0) & (at_max < int(trials) - half) & (est < log_max - 1.5 * step)
    return CalibrationData.from_arrays(
        stimuli.f[keep], est[keep], e=stimuli.e[keep], velocity=stimuli.v[keep],
        luminance=stimuli.luminance[keep], area=stimuli.area[keep], n=1.0,
        **_labels(observer, "2afc"),
    )
