"""Reading the calibration CSV layout (columns: see ``optim.fit._data``), stage by stage.

Every error is a ``pmetric.PlodError`` naming the file, the 1-based line in the file and the column.
"""

from __future__ import annotations

import csv
import io
import math

import numpy as np

from pmetric import PlodError

# base column -> accepted unit suffixes (lower case); "" = no suffix.
_UNITS: dict[str, tuple[str, ...]] = {
    "s_frequency": ("", "cpd", "cycles_per_deg"),
    "t_frequency": ("", "hz"),
    "velocity": ("", "deg_s", "degs", "dps", "deg_per_s"),
    "eccentricity": ("", "deg"),
    "luminance": ("", "cdm2", "cd_m2"),
    "area": ("", "deg2"),
    "vis_field": ("", "deg"),
    "ge_sigma": ("", "deg"),
    "orientation": ("", "deg"),
}
_NUMERIC_OTHER = ("N", "log_cone_contrast", "var_log_cone_contrast", "sensitivity")
_LABELS = ("dataset", "observer", "stimulus", "source")

def _canonical_header(name: str, where: str) -> str | None:
    """Map a header cell to its canonical column name, or None when the column is not ours."""
    raw = name.strip()
    if raw in _NUMERIC_OTHER or raw in _LABELS:
        return raw
    low = raw.lower()
    for base, units in _UNITS.items():
        if low == base:
            return base
        if low.startswith(base + "_"):
            unit = low[len(base) + 1:]
            if unit not in units:
                known = ", ".join(repr(u) for u in units if u)
                raise PlodError(
                    f"{where}: column {raw!r} has unknown unit {unit!r} for {base!r}; "
                    f"accepted: no suffix or {known}"
                )
            return base
    return None


def _parse_float(cell: str, where: str, column: str) -> float:
    s = cell.strip()
    if s == "":
        return math.nan
    try:
        return float(s)
    except ValueError:
        raise PlodError(f"{where}, column {column!r}: {cell!r} is not a number") from None


# ----------------------------------------------------------------------------- CSV reading, by stage
def _read_header(reader, name: str) -> tuple[list[str], dict[str, int]]:
    """The header line and {canonical column: index} of the columns we read."""
    try:
        header = next(reader)
    except StopIteration:
        raise PlodError(f"{name}: empty file (no header line)") from None
    except csv.Error as exc:
        raise PlodError(f"{name}, line 1: malformed CSV ({exc})") from None
    cols: dict[str, int] = {}
    for j, h in enumerate(header):
        c = _canonical_header(h, f"{name}, line 1")
        if c is None:
            continue
        if c in cols:
            raise PlodError(f"{name}, line 1: column {c!r} appears twice (as {header[cols[c]]!r} and {h!r})")
        cols[c] = j
    if "s_frequency" not in cols:
        raise PlodError(f"{name}, line 1: missing required column 's_frequency' (cycles/deg); "
                        f"header is {header}")
    if "log_cone_contrast" not in cols and "sensitivity" not in cols:
        raise PlodError(f"{name}, line 1: missing required column 'log_cone_contrast' "
                        f"(log10 threshold contrast) or 'sensitivity'; header is {header}")
    return header, cols


def _read_cells(reader, header, cols, name: str) -> dict:
    """The data rows: {"vals": numeric columns, "empty": their empty cells, "labs": labels, "lines"}."""
    num_cols = [c for c in cols if c not in _LABELS]
    vals: dict[str, list[float]] = {c: [] for c in num_cols}
    empty: dict[str, list[bool]] = {c: [] for c in num_cols}
    labs: dict[str, list[str]] = {c: [] for c in _LABELS if c in cols}
    lines: list[int] = []
    try:
        for row in reader:
            line = reader.line_num
            if not row or all(not cell.strip() for cell in row):
                continue  # blank line
            if len(row) != len(header):
                raise PlodError(f"{name}, line {line}: {len(row)} cells, the header has {len(header)}")
            where = f"{name}, line {line}"
            for c in num_cols:
                vals[c].append(_parse_float(row[cols[c]], where, header[cols[c]]))
                empty[c].append(not row[cols[c]].strip())
            for c in labs:
                labs[c].append(row[cols[c]].strip())
            lines.append(line)
    except csv.Error as exc:
        raise PlodError(f"{name}, line {reader.line_num}: malformed CSV ({exc})") from None
    if not lines:
        raise PlodError(f"{name}: no data rows after the header")
    return {"vals": vals, "empty": empty, "labs": labs, "lines": lines}


def _check_sensitivity_agrees(lc, s, where):
    """``sensitivity`` must agree with ``log_cone_contrast`` to 1 % where both are given."""
    both = np.isfinite(lc) & np.isfinite(s) & (s > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        bad = both & (np.abs(np.log10(np.where(both, s, 1.0)) + lc) > np.log10(1.01))
    if bad.any():
        i = int(np.argmax(bad))
        raise PlodError(f"{where(i)}, column 'sensitivity': {s[i]} disagrees with "
                        f"log_cone_contrast {lc[i]} (expected {10 ** -lc[i]:.6g})")


def _check_velocity_agrees(tf, v, f, where):
    """``velocity`` must equal ``t_frequency / s_frequency`` where both are given."""
    ok = np.isfinite(tf) & np.isfinite(v) & np.isfinite(f) & (f > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        bad = ok & ~np.isclose(v, tf / np.where(ok, f, 1.0), rtol=1e-3, atol=1e-9)
    if bad.any():
        i = int(np.argmax(bad))
        raise PlodError(f"{where(i)}, column 'velocity': {v[i]} deg/s disagrees with "
                        f"t_frequency / s_frequency = {tf[i] / f[i]:.6g}")


def _csv_columns(cells: dict, name: str, dataset: str):
    """``(arrays, labels, options of _finish)`` from the parsed cells (defaults and cross-checks)."""
    vals, empty, labs, lines = cells["vals"], cells["empty"], cells["labs"], cells["lines"]
    nrows = len(lines)

    def col(c, default):
        return np.asarray(vals[c], dtype=np.float64) if c in vals else np.full(nrows, default)

    where = lambda i: f"{name}, line {lines[i]}"  # noqa: E731
    if "log_cone_contrast" in vals and "sensitivity" in vals:
        _check_sensitivity_agrees(col("log_cone_contrast", np.nan), col("sensitivity", np.nan), where)
    is_log = "log_cone_contrast" in vals
    is_vel = "velocity" in vals and "t_frequency" not in vals
    arrs = {
        "f": col("s_frequency", np.nan),
        "e": col("eccentricity", 0.0),
        "luminance": col("luminance", np.nan),
        "area": col("area", np.nan),
        "n": col("N", 1.0),
        "var_log_threshold": col("var_log_cone_contrast", np.nan),
        "vis_field": col("vis_field", np.nan),
        "ge_sigma": col("ge_sigma", np.nan),
        "orientation": col("orientation", np.nan),
        "thr": col("log_cone_contrast", np.nan) if is_log else col("sensitivity", np.nan),
        "tv": col("velocity", 0.0) if is_vel else col("t_frequency", 0.0),
    }
    # empty optional cells take their defaults (an explicit "NaN" in e / t_frequency is an error)
    if "eccentricity" in vals:
        arrs["e"] = np.where(empty["eccentricity"], 0.0, arrs["e"])
    tv_col = "velocity" if is_vel else "t_frequency"
    if tv_col in vals:
        arrs["tv"] = np.where(empty[tv_col], 0.0, arrs["tv"])
    arrs["n"] = np.where(np.isnan(arrs["n"]), 1.0, arrs["n"])
    if "velocity" in vals and "t_frequency" in vals:
        _check_velocity_agrees(col("t_frequency", 0.0), col("velocity", 0.0), arrs["f"], where)
    labels = {
        "dataset": np.asarray(labs["dataset"], dtype=np.str_) if "dataset" in labs else np.full(nrows, dataset),
        "observer": np.asarray(labs.get("observer", [""] * nrows), dtype=np.str_),
        "stimulus": np.asarray(labs.get("stimulus", [""] * nrows), dtype=np.str_),
        "source": np.asarray(labs.get("source", [""] * nrows), dtype=np.str_),
    }
    return arrs, labels, dict(is_log=is_log, is_velocity=is_vel, where=where,
                              colname={"f": "s_frequency", "e": "eccentricity", "n": "N",
                                       "thr": "log_cone_contrast" if is_log else "sensitivity",
                                       "tv": "velocity" if is_vel else "t_frequency"})


def parse_csv(text: str, name: str, dataset: str):
    """Parse calibration CSV text: ``(arrays, labels, options)`` for the validation of ``_data``."""
    reader = csv.reader(io.StringIO(text))
    header, cols = _read_header(reader, name)
    return _csv_columns(_read_cells(reader, header, cols, name), name, dataset)
