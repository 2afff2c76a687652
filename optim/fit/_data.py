"""Psychophysical contrast-threshold data for calibrating and fitting CSF models.

``CalibrationData`` reads the CSV layout of the Mantiuk group's achromatic threshold collections
(castleCSF / stelaCSF: [Ash24], [MAC22]) and of per-user calibrations ([LH01 §6.1]: threshold contrast
over frequency x eccentricity).

CSV columns (header names; order free, extra columns ignored)
-------------------------------------------------------------

Required:

* ``s_frequency`` -- spatial frequency, cycles/deg (>= 0; 0 only for disk stimuli with no drift).
* ``log_cone_contrast`` (log10 threshold Michelson contrast) **or** ``sensitivity`` (1 / threshold
  contrast, > 0). When both are present ``log_cone_contrast`` is used and ``sensitivity`` must agree with
  it to 1 %.

Optional (defaults when the column is absent or a cell is empty):

* ``t_frequency`` -- temporal frequency, Hz (default 0), **or** ``velocity`` -- retinal velocity, deg/s.
  Velocity = t_frequency / s_frequency (a drifting grating); both columns present must agree.
* ``eccentricity`` -- deg (default 0).
* ``luminance`` -- cd/m2 (default NaN = "unknown"; luminance models fall back to their default field).
* ``area`` -- stimulus area, deg2 (default NaN = unknown).
* ``vis_field`` (deg), ``ge_sigma`` (deg), ``orientation`` (deg) -- default NaN.
* ``N`` -- number of observers / repeats behind the row, used as the row weight (default 1).
* ``var_log_cone_contrast`` -- variance of the log10 threshold (default NaN; ``Inf`` allowed).
* ``dataset`` (default: the file's stem), ``observer`` (default ``""`` = pooled), ``stimulus``,
  ``source`` -- labels.

A numeric header may carry a unit suffix, e.g. ``s_frequency_cpd``, ``t_frequency_hz``,
``luminance_cdm2``, ``area_deg2``, ``eccentricity_deg`` (as in ``reference_values_achromatic.csv``);
an unknown suffix (``s_frequency_cpm``) is an error rather than a silent unit mismatch.

Every error is a ``pmetric.PlodError`` (a ``ValueError``) naming the file, the 1-based line in the file
and the column.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path
from typing import Iterable

import numpy as np

from pmetric import PlodError, atomic_path
from pmetric._base import check_broadcast

from ._csv import parse_csv

__all__ = ["CalibrationData"]

_FLOAT_FIELDS = (
    "f", "t_frequency", "velocity", "e", "luminance", "area", "log_threshold", "n",
    "var_log_threshold", "vis_field", "ge_sigma", "orientation",
)
_STR_FIELDS = ("dataset", "observer", "stimulus", "source")

# CSV column written for each field by ``to_csv`` (order of the shared files).
_CSV_OUT = (
    ("dataset", "dataset"), ("observer", "observer"), ("luminance", "luminance"),
    ("s_frequency", "f"), ("t_frequency", "t_frequency"), ("velocity", "velocity"),
    ("eccentricity", "e"), ("vis_field", "vis_field"), ("area", "area"), ("ge_sigma", "ge_sigma"),
    ("stimulus", "stimulus"), ("orientation", "orientation"), ("N", "n"),
    ("log_cone_contrast", "log_threshold"), ("var_log_cone_contrast", "var_log_threshold"),
    ("sensitivity", None), ("source", "source"),
)


class CalibrationData:
    """Contrast thresholds, one row per stimulus condition (numpy arrays of length ``len(self)``).

    Attributes (all numpy arrays of shape (n,)):

    * ``f`` spatial frequency (cycles/deg), ``t_frequency`` (Hz), ``velocity`` retinal velocity (deg/s,
      = t_frequency / f, 0 for static stimuli), ``e`` eccentricity (deg), ``luminance`` (cd/m2, NaN =
      unknown), ``area`` (deg2, NaN = unknown), ``vis_field``, ``ge_sigma``, ``orientation`` (deg),
    * ``log_threshold`` log10 threshold Michelson contrast, ``n`` row weight (observers/repeats),
      ``var_log_threshold`` variance of ``log_threshold`` (NaN unknown),
    * ``dataset``, ``observer``, ``stimulus``, ``source``: string labels.

    Derived: ``threshold`` (= 10**log_threshold), ``sensitivity`` (= 1/threshold), ``weights`` (= n).
    Instances are immutable in spirit: arrays are made read-only.
    """

    __slots__ = _FLOAT_FIELDS + _STR_FIELDS

    def __init__(self, **fields):
        missing = [k for k in _FLOAT_FIELDS + _STR_FIELDS if k not in fields]
        extra = [k for k in fields if k not in _FLOAT_FIELDS + _STR_FIELDS]
        if missing or extra:
            raise PlodError(f"CalibrationData: missing fields {missing}, unknown fields {extra}; "
                             "use CalibrationData.from_arrays or from_csv")
        n = None
        for k in _FLOAT_FIELDS + _STR_FIELDS:
            a = np.asarray(fields[k], dtype=np.float64 if k in _FLOAT_FIELDS else np.str_)
            if a.ndim != 1:
                raise PlodError(f"CalibrationData: field {k!r} must be 1-D, got shape {a.shape}")
            if n is None:
                n = a.shape[0]
            elif a.shape[0] != n:
                raise PlodError(f"CalibrationData: field {k!r} has {a.shape[0]} rows, expected {n}")
            a = a.copy()
            a.setflags(write=False)
            object.__setattr__(self, k, a)

    def __setattr__(self, key, value):
        raise AttributeError("CalibrationData is immutable; use subset() or from_arrays()")

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_arrays(
        cls,
        f,
        log_threshold=None,
        *,
        sensitivity=None,
        e=0.0,
        t_frequency=None,
        velocity=None,
        luminance=np.nan,
        area=np.nan,
        n=1.0,
        var_log_threshold=np.nan,
        vis_field=np.nan,
        ge_sigma=np.nan,
        orientation=np.nan,
        dataset="data",
        observer="",
        stimulus="",
        source="",
    ) -> "CalibrationData":
        """Build from arrays (broadcast against each other to 1-D).

        Give exactly one of ``log_threshold`` (log10 threshold contrast) or ``sensitivity`` (> 0), and
        at most one of ``t_frequency`` (Hz) and ``velocity`` (deg/s; default 0). Values are validated
        like CSV cells; errors name the offending row (0-based index) and field.
        """
        if (log_threshold is None) == (sensitivity is None):
            raise PlodError("from_arrays: give exactly one of log_threshold and sensitivity")
        if t_frequency is not None and velocity is not None:
            raise PlodError("from_arrays: give at most one of t_frequency (Hz) and velocity (deg/s)")
        num = {
            "f": f, "e": e, "luminance": luminance, "area": area, "n": n,
            "var_log_threshold": var_log_threshold, "vis_field": vis_field, "ge_sigma": ge_sigma,
            "orientation": orientation,
            "thr": log_threshold if log_threshold is not None else sensitivity,
            "tv": t_frequency if t_frequency is not None else (velocity if velocity is not None else 0.0),
        }
        try:
            arrs = {k: np.asarray(v, dtype=np.float64) for k, v in num.items()}
        except (TypeError, ValueError) as exc:
            raise PlodError(f"from_arrays: numeric input is not numeric ({exc})") from None
        labels = {k: np.asarray(v, dtype=np.str_) for k, v in
                  {"dataset": dataset, "observer": observer, "stimulus": stimulus, "source": source}.items()}
        shape = check_broadcast("from_arrays", **{k: a.shape for k, a in {**arrs, **labels}.items()})
        if len(shape) > 1:
            raise PlodError(f"from_arrays: inputs must be scalars or 1-D, broadcast shape is {shape}")
        arrs = {k: np.broadcast_to(a, shape).reshape(-1) for k, a in arrs.items()}
        labels = {k: np.broadcast_to(a, shape).reshape(-1) for k, a in labels.items()}
        fields = _finish(arrs, labels, is_log=log_threshold is not None,
                         is_velocity=velocity is not None, where=lambda i: f"from_arrays: row {i}")
        return cls(**fields)

    @classmethod
    def from_csv(cls, path: str | os.PathLike, *, dataset: str | None = None) -> "CalibrationData":
        """Read a CSV file (see the module docstring for the columns).

        ``dataset`` labels rows whose file has no ``dataset`` column (default: the file stem).
        """
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8-sig")
        except FileNotFoundError:
            raise PlodError(f"calibration file {str(p)!r} does not exist") from None
        except UnicodeDecodeError as exc:
            raise PlodError(f"calibration file {str(p)!r} is not UTF-8 text ({exc.reason})") from None
        return cls.from_csv_text(text, name=str(p), dataset=dataset if dataset is not None else p.stem)

    @classmethod
    def from_csv_text(cls, text: str, *, name: str = "<csv>", dataset: str = "data") -> "CalibrationData":
        """Parse CSV text (same rules as ``from_csv``); ``name`` appears in error messages."""
        arrs, labels, opts = parse_csv(text, name, dataset)
        return cls(**_finish(arrs, labels, **opts))

    # ------------------------------------------------------------------ derived values
    @property
    def threshold(self) -> np.ndarray:
        """Threshold Michelson contrast, 10**log_threshold, shape (n,)."""
        return 10.0 ** self.log_threshold

    @property
    def sensitivity(self) -> np.ndarray:
        """Contrast sensitivity 1/threshold, shape (n,)."""
        return 10.0 ** (-self.log_threshold)

    @property
    def weights(self) -> np.ndarray:
        """Row weights for fitting: the ``N`` column (observers / repeats; 1 when absent), shape (n,)."""
        return self.n

    @property
    def datasets(self) -> list[str]:
        """Distinct dataset labels in order of first appearance."""
        return list(dict.fromkeys(self.dataset.tolist()))

    @property
    def observers(self) -> list[str]:
        """Distinct observer labels in order of first appearance (``""`` = pooled rows)."""
        return list(dict.fromkeys(self.observer.tolist()))

    def __len__(self) -> int:
        return int(self.f.shape[0])

    def __repr__(self) -> str:
        return f"CalibrationData({len(self)} rows, datasets={self.datasets})"

    # ------------------------------------------------------------------ selection
    def subset(self, mask) -> "CalibrationData":
        """Rows selected by a boolean mask of shape (n,) or an integer index array."""
        m = np.asarray(mask)
        if m.dtype == bool:
            if m.shape != (len(self),):
                raise PlodError(f"subset: boolean mask has shape {m.shape}, expected ({len(self)},)")
        elif np.issubdtype(m.dtype, np.integer):
            if m.ndim != 1:
                raise PlodError(f"subset: index array must be 1-D, got shape {m.shape}")
            if m.size and (m.max() >= len(self) or m.min() < -len(self)):
                raise PlodError(f"subset: index out of range for {len(self)} rows")
        else:
            raise PlodError(f"subset: mask must be boolean or integer, got dtype {m.dtype}")
        return CalibrationData(**{k: getattr(self, k)[m] for k in _FLOAT_FIELDS + _STR_FIELDS})

    def by_dataset(self) -> dict[str, "CalibrationData"]:
        """Split into one ``CalibrationData`` per dataset label (order of first appearance)."""
        return {d: self.subset(self.dataset == d) for d in self.datasets}

    def by_observer(self) -> dict[str, "CalibrationData"]:
        """Split into one ``CalibrationData`` per observer label (order of first appearance)."""
        return {o: self.subset(self.observer == o) for o in self.observers}

    @staticmethod
    def concatenate(parts: Iterable["CalibrationData"]) -> "CalibrationData":
        """Stack several data sets row-wise."""
        parts = list(parts)
        if not parts:
            raise PlodError("concatenate: no data sets given")
        return CalibrationData(**{k: np.concatenate([getattr(p, k) for p in parts])
                                  for k in _FLOAT_FIELDS + _STR_FIELDS})

    # ------------------------------------------------------------------ output
    def summary(self) -> str:
        """A short human-readable table: rows, datasets, observers and the ranges of each input."""
        lines = [f"CalibrationData: {len(self)} rows, {len(self.datasets)} datasets, "
                 f"{len([o for o in self.observers if o])} named observers"]

        def rng(name, a, unit):
            a = a[np.isfinite(a)]
            if a.size == 0:
                return f"  {name:<14} (unknown)"
            return f"  {name:<14} {a.min():.4g} .. {a.max():.4g} {unit}"

        lines += [
            rng("frequency", self.f, "cycles/deg"),
            rng("velocity", self.velocity, "deg/s"),
            rng("eccentricity", self.e, "deg"),
            rng("luminance", self.luminance, "cd/m2"),
            rng("area", self.area, "deg2"),
            rng("log10 thresh.", self.log_threshold, ""),
        ]
        for d in self.datasets:
            m = self.dataset == d
            lines.append(f"  - {d}: {int(m.sum())} rows")
        return "\n".join(lines)

    def to_csv(self, path: str | os.PathLike) -> Path:
        """Write the rows as CSV (the shared files' column names) atomically; returns the path."""
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow([c for c, _ in _CSV_OUT])
        cols = []
        for c, fld in _CSV_OUT:
            if fld is None:
                cols.append([repr(float(x)) for x in self.sensitivity])
            elif fld in _STR_FIELDS:
                cols.append(getattr(self, fld).tolist())
            else:
                cols.append([repr(float(x)) for x in getattr(self, fld)])
        for row in zip(*cols):
            w.writerow(row)
        with atomic_path(path) as tmp:
            tmp.write_text(buf.getvalue(), encoding="utf-8")
        return Path(path)


def _finish(arrs, labels, *, is_log, is_velocity, where, colname=None) -> dict:
    """Validate parsed numeric columns and derive threshold / velocity fields."""
    colname = colname or {}
    cn = lambda k: colname.get(k, {"thr": "log_threshold" if is_log else "sensitivity",  # noqa: E731
                                   "tv": "velocity" if is_velocity else "t_frequency"}.get(k, k))

    def fail(mask, k, msg):
        if mask.any():
            i = int(np.argmax(mask))
            raise PlodError(f"{where(i)}, column {cn(k)!r}: {msg} (got {arrs[k][i].item()!r})")

    # required, finite
    for k in ("f", "thr", "e", "tv"):
        fail(~np.isfinite(arrs[k]), k, "missing, NaN or infinite value")
    fail(arrs["f"] < 0, "f", "negative spatial frequency (cycles/deg)")
    fail(arrs["e"] < 0, "e", "negative eccentricity (deg)")
    fail(arrs["tv"] < 0, "tv", "negative temporal frequency / velocity")
    if not is_log:
        fail(arrs["thr"] <= 0, "thr", "sensitivity must be > 0")
    for k, what in (("luminance", "luminance (cd/m2)"), ("area", "area (deg2)")):
        fail(~np.isnan(arrs[k]) & ~(arrs[k] > 0) | np.isinf(arrs[k]), k, f"{what} must be > 0 and finite")
    fail(~(arrs["n"] > 0) | np.isinf(arrs["n"]), "n", "weight N must be > 0 and finite")
    fail(arrs["var_log_threshold"] < 0, "var_log_threshold", "variance must be >= 0")
    if is_log:
        log_thr = arrs["thr"]
        fail(log_thr > np.log10(1e6), "thr", "log10 threshold contrast implausibly large")
    else:
        log_thr = -np.log10(arrs["thr"])
    f = arrs["f"]
    if is_velocity:
        v = arrs["tv"]
        tf = v * f
        fail((f == 0) & (v > 0), "tv", "velocity > 0 with s_frequency 0")
    else:
        tf = arrs["tv"]
        fail((f == 0) & (tf > 0), "tv", "temporal frequency > 0 with s_frequency 0 (velocity undefined)")
        with np.errstate(divide="ignore", invalid="ignore"):
            v = np.where(tf > 0, tf / np.where(f > 0, f, 1.0), 0.0)
    out = {
        "f": f, "t_frequency": tf, "velocity": v, "e": arrs["e"], "luminance": arrs["luminance"],
        "area": arrs["area"], "log_threshold": log_thr, "n": arrs["n"],
        "var_log_threshold": arrs["var_log_threshold"], "vis_field": arrs["vis_field"],
        "ge_sigma": arrs["ge_sigma"], "orientation": arrs["orientation"],
    }
    out.update(labels)
    return out

