"""``plod calibrate --simulate``: write the CSV of a simulated calibration session.

[LH01 §6.1] calibrates a per-user CSF from gratings that fade in until the user responds. Without
a display and an observer this command simulates the session (``pmetric._simulate``): a
``SimulatedObserver`` whose thresholds are a named pmetric model's, with log-normal psychometric noise,
run through the fade-in method of adjustment or a 2AFC staircase over a grid of frequencies (cycles/deg)
x eccentricities (deg) x velocities (deg/s). The output is a ``CalibrationData`` CSV (written
atomically; never over an input file) that ``plod fit`` can read.

Example::

    plod calibrate --simulate --model stela --method staircase --grid 1,2,4,8x0,10x0 --out sim.csv
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from experiments._paths import check_output
from pmetric import PlodError, make_model


def _parse_list(text: str, what: str) -> np.ndarray:
    try:
        vals = np.array([float(t) for t in text.split(",") if t.strip() != ""], dtype=float)
    except ValueError:
        raise PlodError(f"--grid: {what} list {text!r} is not a comma-separated list of numbers") from None
    if vals.size == 0 or not np.isfinite(vals).all():
        raise PlodError(f"--grid: {what} list {text!r} must hold finite numbers")
    return vals


def parse_grid(text: str):
    """``"F1,F2,...xE1,...xV1,..."`` -> (freqs cycles/deg, eccs deg, vels deg/s); eccs/vels default to 0."""
    parts = text.lower().split("x")
    if not 1 <= len(parts) <= 3:
        raise PlodError(f"--grid {text!r}: expected FREQS[xECCS[xVELS]] with comma-separated numbers")
    names = ("frequency", "eccentricity", "velocity")
    lists = [_parse_list(p, n) for p, n in zip(parts, names)]
    while len(lists) < 3:
        lists.append(np.zeros(1))
    f, e, v = lists
    if (f <= 0).any():
        raise PlodError("--grid: frequencies must be > 0 cycles/deg")
    if (e < 0).any() or (v < 0).any():
        raise PlodError("--grid: eccentricities and velocities must be >= 0")
    return f, e, v


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "calibrate", help="simulate a calibration session [LH01 §6.1] and write its CSV",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--simulate", action="store_true",
                   help="simulate the observer (required: a real session needs a calibrated display)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--model", default="stela", metavar="NAME|FILE.json",
                     help="the observer's model: a name (see plod models), eccentric(NAME) or a saved model "
                          ".json (default stela: it depends on every stimulus dimension)")
    src.add_argument("--model-file", type=Path, help="a model saved with pmetric.save_model (JSON)")
    p.add_argument("--method", choices=("fade", "staircase"), default="fade",
                   help="fade-in method of adjustment [LH01 §6.1] or 2AFC staircase")
    p.add_argument("--observer-seed", type=int, default=0, help="random seed of the simulated observer")
    p.add_argument("--noise", type=float, default=0.15,
                   help="psychometric spread: s.d. of the detection contrast in log10 units (0 = noise-free)")
    p.add_argument("--lapse", type=float, default=0.0, help="lapse rate in [0, 1)")
    p.add_argument("--grid", default="0.5,1,2,4,8,16x0,5,10,20x0",
                   help="FREQS[xECCS[xVELS]]: comma lists in cycles/deg, deg and deg/s")
    p.add_argument("--luminance", type=float, default=float("nan"), help="background luminance, cd/m2")
    p.add_argument("--area", type=float, default=float("nan"), help="stimulus area, deg2")
    p.add_argument("--rate-db", type=float, default=6.0, help="fade-in rate, dB of contrast per second")
    p.add_argument("--reaction-time", type=float, default=0.4, help="reaction time, s")
    p.add_argument("--rule", default=None,
                   help="staircase rule (1down1up .. 4down1up; default 3down1up); needs --method staircase")
    p.add_argument("--trials", type=int, default=None,
                   help="staircase trials per stimulus (default 80); needs --method staircase")
    p.add_argument("--repeats", type=int, default=1, help="sessions per grid point")
    p.add_argument("--out", type=Path, required=True, help="output CSV path")
    p.set_defaults(func=run)


def run(args) -> int:
    from optim.fit import CalibrationData, SimulatedObserver, fade_in_session, staircase_2afc, stimulus_grid

    if not args.simulate:
        raise PlodError("only --simulate is supported: a real calibration needs a photometrically calibrated "
                        "display and an observer")
    if not (args.noise >= 0 and math.isfinite(args.noise)):
        raise PlodError(f"--noise must be a finite number >= 0, got {args.noise}")
    if args.repeats < 1:
        raise PlodError(f"--repeats must be >= 1, got {args.repeats}")
    for name, val in (("--luminance", args.luminance), ("--area", args.area)):
        if not math.isnan(val) and not (val > 0 and math.isfinite(val)):
            raise PlodError(f"{name} must be a positive number, got {val}")
    if args.method != "staircase":
        for flag, val in (("--rule", args.rule), ("--trials", args.trials)):
            if val is not None:
                raise PlodError(f"{flag} applies to --method staircase only; the fade-in method has no {flag[2:]}")
    rule = "3down1up" if args.rule is None else args.rule
    trials = 80 if args.trials is None else args.trials
    if not 2 <= trials <= 100_000:  # a Python loop per trial: 1e9 trials ran for hours without a word
        raise PlodError(f"--trials must be in 2..100000, got {trials}")
    if args.observer_seed < 0:
        raise PlodError(f"--observer-seed must be >= 0, got {args.observer_seed}")
    check_output("--out", args.out, suffixes=(".csv",), inputs=(args.model_file, args.model))
    if args.model_file is not None and not args.model_file.is_file():
        raise PlodError(f"--model-file {args.model_file} does not exist")
    model = make_model(args.model_file if args.model_file is not None else args.model)
    out = args.out
    f, e, v = parse_grid(args.grid)
    stimuli = stimulus_grid(f, e, v, luminance=args.luminance, area=args.area)
    slope = math.inf if args.noise == 0 else 1.0 / args.noise
    observer = SimulatedObserver(model, slope=slope, lapse=args.lapse, seed=args.observer_seed)
    parts = []
    for _ in range(args.repeats):
        if args.method == "fade":
            parts.append(fade_in_session(observer, stimuli, args.rate_db, args.reaction_time))
        else:
            parts.append(staircase_2afc(observer, stimuli, rule=rule, trials=trials))
    data = CalibrationData.concatenate(parts)
    if len(data) == 0:
        c_t = np.asarray(observer.threshold(stimuli), np.float64)
        if np.all(c_t >= 1.0):
            raise PlodError("no grating of the grid was visible to the simulated observer; nothing written")
        raise PlodError(f"no threshold of the grid could be measured by --method {args.method} (the model's "
                        f"thresholds span {np.nanmin(c_t):.3g}..{np.nanmax(c_t):.3g} in Michelson contrast, "
                        "beyond what the method measures); nothing written")
    data.to_csv(out)  # CalibrationData.to_csv writes atomically
    print(f"wrote {len(data)} of {len(stimuli) * args.repeats} simulated thresholds "
          f"({args.method}, {type(model).__name__}, seed {args.observer_seed}) to {out}")
    return 0
