"""``plod experiment``: a batch runner of judged simplification sweeps that survives interruption and
grows past one machine (issue 11).

    plod experiment CONFIG.toml [--workers N] [--scheduler tcp://HOST:PORT] [--resume] [--out DIR]
    .venv/bin/python -m experiments.experiment CONFIG.toml [...]     (the same, before ``plod`` lists it)

A config is a short TOML file of overrides on :data:`DEFAULTS` (nanoGPT style; ``base = "other.toml"``
layers it on another config, relative to its own folder). Unknown keys and bad values are refused
with the key's name and its line in the file.

**Cells.** One cell is one method at one (mesh, view, gaze offset, lighting, budget): every mesh
(``meshes``: files; ``procedural``: ``"sphere:SUBDIV:SEED"`` = ``optim.bumpy_sphere`` with colours,
``"torus:NU:NV:SEED"`` = ``optim.bumpy_torus``) x ``views`` random view directions (seeded by ``seed`` and
the mesh name; the object framed at ``object_deg`` deg of the display's visual field, ``optim.View.framing``)
x ``gaze_offsets_deg`` (deg of visual angle to the right of the object's centre, gaze error
``gaze_error_deg``) x ``lightings`` (``relit``: rendered from each mesh's own normals with
``optim.Lighting()``, the light in the view; ``baked``: vertex colours, for an uncoloured mesh the
original's lighting baked into grey) x ``budgets`` (a float in (0, 1]: a fraction of the input
triangles; an integer >= 1: a triangle count) x ``methods``:

* ``perceptual``, ``size``, ``geometric``: plod's keys (``optim.score(tree, view, None, metric)``) cut
  with ``optim.budget_cut``; the perceptual cut's triangle count is the count every other method of
  the cell's budget is cut or simplified to ("the same triangle count");
* ``imperceptible``: ``optim.threshold_cut`` at distance 1 (no budget: one cell per view);
* ``model:NAME`` (any name of ``plod models``, ``pmetric.make_model``) or ``PATH.json`` (a fitted model
  file): perceptual keys of that model at the perceptual cut's count;
* ``meshoptimizer``, ``fast_simplification``: the view-independent peers (``experiments.peers``).

Every result is scored by ``judges``: ``fovvdp`` (FovVideoVDP [Man21] JOD foveated at the gaze, 10 =
indistinguishable), ``flip`` (mean FLIP [And20], 0 = identical), both on renderings at ``judge_size``
pixels with the display's angular content (``experiments.judge``), and ``distance`` (plod's own
imperceptible distance of a tree cut: the largest default-model perceptual key among its folded nodes;
1 = at threshold; none for the peers).

**Results.** One row per cell (:data:`COLUMNS`): ids, triangles, every judge's score, the seconds of each
stage (tree build, score, cut, extract, peer simplify, judge; the first cell of a method on a worker
runs it once before, untimed but for ``time_warmup_s``, so XLA compilation stays out of the stage
times), the worker, plod's version, the git SHA
and the package versions. A failed cell records ``error`` and the sweep goes on. Finished rows are
appended to ``OUT/results.jsonl`` (flushed and fsynced per row); ``--resume`` keeps them and runs only
the cells missing (and those that failed); at the end ``OUT/results.parquet`` (with pyarrow) or
``OUT/results.csv`` holds the rows in cell order, and ``OUT/report.md`` with its PNGs and
``OUT/run_info.json`` are written (``experiments._experiment_report``). Cells are deterministic: a
resumed, local or Dask run gives the same rows, timings and workers apart.

**Execution.** ``workers`` local processes (``concurrent.futures``, spawned; 0: in this process) or a
Dask cluster (``scheduler``: ``dask.distributed.Client(address)``). A worker builds each (mesh,
lighting) tree once and caches it (``functools.lru_cache``). ``progress(stage, done, total)`` is called
once per finished cell; the library prints nothing.
"""

from __future__ import annotations

import functools
import json
import math
import os
import re
import sys
import threading
import time
import tomllib
from pathlib import Path
from typing import Any, Callable

import numpy as np

from experiments._runinfo import check_out_dir, load_config, repo_path
from pmetric import PlodError, atomic_write_text

__all__ = ["DEFAULTS", "COLUMNS", "load_experiment_config", "cells", "run_cell", "run_experiment",
           "view_directions", "baked_grey", "procedural_mesh", "perceptual_distance", "pareto_front"]

# what a run and its report write into the output folder (check_out_dir)
WRITES = ("results.jsonl", "experiment.json", "results.parquet", "results.csv", "report.md", "*.png")

DEFAULTS: dict[str, Any] = {
    "base": "",  # a config this one overrides (relative to this file's folder); "" none
    "out": "reports/experiments/default",
    "seed": 2026,
    "meshes": [],  # mesh files (PLY, OBJ, ...; relative paths from the repository root)
    "missing_meshes": "error",  # "error" or "skip" (files absent here, e.g. ../shared data)
    "procedural": ["sphere:4:11"],  # "sphere:SUBDIV:SEED" or "torus:NU:NV:SEED"
    "tree_method": "meshopt",  # optim.build_tree's method: meshopt, qem, octree
    "views": 1,
    "object_deg": 30.0,
    "gaze_offsets_deg": [0.0],
    "gaze_error_deg": 1.0,
    "lightings": ["relit"],
    "budgets": [0.08],
    "methods": ["imperceptible", "perceptual", "size", "geometric", "meshoptimizer", "fast_simplification"],
    "judges": ["fovvdp", "flip", "distance"],
    "judge_size": [480, 270],
    "examples": 1,  # best and worst cells re-judged with FovVideoVDP/FLIP maps in the report
}

KEY_METHODS = ("perceptual", "size", "geometric")
PEERS = ("meshoptimizer", "fast_simplification")
JUDGES = ("fovvdp", "flip", "distance")
SCORE_COLUMNS = {"fovvdp": "jod", "flip": "flip", "distance": "distance"}
TIME_COLUMNS = ("time_tree_s", "time_warmup_s", "time_score_s", "time_cut_s", "time_extract_s", "time_peer_s", "time_judge_s",
                "time_cell_s")
COLUMNS = ("index", "cell", "mesh", "view", "dir_x", "dir_y", "dir_z", "gaze_deg", "lighting", "budget",
           "target_triangles", "method", "input_triangles", "triangles", "jod", "flip", "distance", "error",
           *TIME_COLUMNS, "worker", "plod_version", "git_sha", "versions")
VOLATILE = (*TIME_COLUMNS, "worker")  # what differs between equal runs
SWEEP_KEYS = tuple(k for k in DEFAULTS if k not in ("base", "out", "examples"))  # what a resumed run must share


# ----------------------------------------------------------------------------------------------- config
_KEY_RE = re.compile(r'^\s*("(?:[^"\\]|\\.)*"|\'[^\']*\'|[A-Za-z0-9_\-]+)\s*=')
_TABLE_RE = re.compile(r"^\s*\[+\s*([^\]]+?)\s*\]+")


def key_lines(text: str) -> dict[str, int]:
    """{dotted key: 1-based line} of the keys a TOML text assigns (top-level keys and table headers)."""
    out: dict[str, int] = {}
    table = ""
    for i, line in enumerate(text.splitlines(), 1):
        m = _TABLE_RE.match(line)
        if m:
            table = m.group(1).strip().strip("\"'")
            out.setdefault(table, i)
            continue
        m = _KEY_RE.match(line)
        if m:
            key = m.group(1).strip("\"'")
            out.setdefault(f"{table}.{key}" if table else key, i)
    return out


class _Where:
    """Where a key came from: ``'KEY' (FILE line N)`` for the message of a refused key."""

    def __init__(self, path: Path | None, lines: dict[str, int]):
        self.path, self.lines = path, lines

    def __call__(self, key: str) -> str:
        if self.path is not None and key in self.lines:
            return f"{key!r} ({self.path} line {self.lines[key]})"
        return repr(key)


def _layer(path: Path, defaults: dict, depth: int = 0) -> tuple[dict, _Where]:
    """``defaults`` overridden by the config at ``path`` (and its ``base`` chain first)."""
    if depth > 8:
        raise PlodError(f"config {path}: 'base' chain deeper than 8 (a cycle?)")
    if not path.is_file():
        raise FileNotFoundError(f"config file not found: {path}")
    try:
        text = path.read_text(encoding="utf-8")
        raw = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise PlodError(f"malformed TOML in {path}: {exc}") from None
    where = _Where(path, key_lines(text))
    for key in raw:
        if key not in DEFAULTS:
            raise PlodError(f"unknown config key {where(key)}; known keys: {', '.join(sorted(DEFAULTS))}")
    base = raw.get("base", "")
    if base:
        if not isinstance(base, str):
            raise PlodError(f"config key {where('base')} must be a file name, got {base!r}")
        bp = Path(base) if Path(base).is_absolute() else path.parent / base
        defaults, _ = _layer(bp, defaults, depth + 1)
    try:
        cfg = load_config(path, {**defaults, "base": ""})
    except PlodError as exc:  # a type error of _runinfo's loader: add the line of its key
        m = re.search(r"config key '([^']+)'", str(exc))
        if m:
            raise PlodError(str(exc).replace(repr(m.group(1)), where(m.group(1)), 1)) from None
        raise
    cfg["base"] = str(path)
    return cfg, where


def load_experiment_config(path: str | Path | None, **overrides) -> dict:
    """The resolved config: :data:`DEFAULTS` overridden by the TOML file at ``path`` (None: defaults)
    and then by ``overrides`` (e.g. ``out``); values checked. PlodError naming the key (and its line)."""
    if path is None:
        cfg, where = dict(DEFAULTS), _Where(None, {})
    else:
        cfg, where = _layer(Path(path), dict(DEFAULTS))
    cfg.update({k: v for k, v in overrides.items() if v is not None})
    return check_config(cfg, where)


def _num(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _method_ok(m) -> bool:
    return isinstance(m, str) and (m in ("imperceptible", *KEY_METHODS, *PEERS) or m.startswith("model:")
                                   or m.lower().endswith(".json"))


def check_config(cfg: dict, where: Callable[[str], str] = repr) -> dict:
    """Check the values of a resolved config (in place; lists normalised); PlodError naming the key."""

    def bad(key, want):
        raise PlodError(f"config key {where(key)} must be {want}, got {cfg[key]!r}")

    if not all(isinstance(m, str) for m in cfg["meshes"]):
        bad("meshes", "a list of mesh file paths")
    if cfg["missing_meshes"] not in ("error", "skip"):
        bad("missing_meshes", "'error' or 'skip'")
    for spec in cfg["procedural"]:
        if not isinstance(spec, str) or _parse_procedural(spec) is None:
            raise PlodError(f"config key {where('procedural')}: {spec!r} is not 'sphere:SUBDIV:SEED' (SUBDIV 0..8) "
                            "or 'torus:NU:NV:SEED' (NU, NV 3..4096, NU x NV <= 2^22; SEED >= 0)")
    if not cfg["meshes"] and not cfg["procedural"]:
        raise PlodError(f"config: no meshes (keys {where('meshes')} and {where('procedural')} are both empty)")
    if cfg["tree_method"] not in ("meshopt", "qem", "octree"):
        bad("tree_method", "'meshopt', 'qem' or 'octree'")
    if not isinstance(cfg["views"], int) or isinstance(cfg["views"], bool) or cfg["views"] < 1:
        bad("views", "an integer >= 1")
    if not isinstance(cfg["seed"], int) or isinstance(cfg["seed"], bool) or cfg["seed"] < 0:
        bad("seed", "an integer >= 0")
    if not 0 < cfg["object_deg"] < 180:
        bad("object_deg", "an angle in (0, 180) deg")
    g = cfg["gaze_offsets_deg"]
    if not g or not all(_num(x) and 0 <= x < 80 for x in g):
        bad("gaze_offsets_deg", "a non-empty list of angles in [0, 80) deg")
    cfg["gaze_offsets_deg"] = [float(x) for x in g]
    if not (_num(cfg["gaze_error_deg"]) and 0 <= cfg["gaze_error_deg"] < 90):
        bad("gaze_error_deg", "an angle in [0, 90) deg")
    lt = cfg["lightings"]
    if not lt or not all(isinstance(x, str) and x in ("relit", "baked") for x in lt) or len(set(lt)) != len(lt):
        bad("lightings", "a non-empty list of distinct 'relit', 'baked'")
    b = cfg["budgets"]
    ok = all((isinstance(x, float) and 0 < x <= 1) or (isinstance(x, int) and not isinstance(x, bool) and x >= 1)
             for x in b)
    if not b or not ok or len({(type(x), x) for x in b}) != len(b):  # 1 (a triangle) and 1.0 (all) differ
        bad("budgets", "a non-empty list of distinct fractions in (0, 1] (floats) or triangle counts >= 1 (integers)")
    m = cfg["methods"]
    if not m or not all(_method_ok(x) for x in m) or len(set(m)) != len(m):
        bad("methods", "a non-empty list of distinct imperceptible, perceptual, size, geometric, meshoptimizer, "
                       "fast_simplification, model:NAME or PATH.json")
    for x in m:
        if x.startswith("model:") or x.lower().endswith(".json"):
            try:
                _model(_model_spec(x))
            except (PlodError, FileNotFoundError) as exc:
                raise PlodError(f"config key {where('methods')}: {x!r}: {exc}") from None
    j = cfg["judges"]
    if not j or not all(isinstance(x, str) and x in JUDGES for x in j) or len(set(j)) != len(j):
        bad("judges", f"a non-empty list of distinct {', '.join(JUDGES)}")
    s = cfg["judge_size"]
    if len(s) != 2 or not all(isinstance(x, int) and not isinstance(x, bool) and 16 <= x <= 8192 for x in s):
        bad("judge_size", "two integers in 16..8192 (width, height in pixels)")
    if not isinstance(cfg["examples"], int) or isinstance(cfg["examples"], bool) or cfg["examples"] < 0:
        bad("examples", "an integer >= 0")
    return cfg


# ----------------------------------------------------------------------------------------------- inputs
def _parse_procedural(spec: str):
    kind, *nums = spec.split(":")
    try:
        nums = [int(x) for x in nums]
    except ValueError:
        return None
    if not nums or nums[-1] < 0:  # the seed
        return None
    if kind == "sphere" and len(nums) == 2 and 0 <= nums[0] <= 8:
        return kind, nums
    if kind == "torus" and len(nums) == 3 and 3 <= nums[0] <= 4096 and 3 <= nums[1] <= 4096 and nums[0] * nums[1] <= 1 << 22:
        return kind, nums
    return None


def procedural_mesh(spec: str):
    """``(vertices, faces, colors or None)`` of ``"sphere:SUBDIV:SEED"`` (``optim.bumpy_sphere``, coloured)
    or ``"torus:NU:NV:SEED"`` (``optim.bumpy_torus``, uncoloured); PlodError for another spelling."""
    import optim

    parsed = _parse_procedural(spec)
    if parsed is None:
        raise PlodError(f"config key 'procedural': {spec!r} is not 'sphere:SUBDIV:SEED' or 'torus:NU:NV:SEED'")
    kind, n = parsed
    if kind == "sphere":
        return optim.bumpy_sphere(n[0], seed=n[1], colors=True)
    v, f = optim.bumpy_torus(n[0], n[1], seed=n[2])
    return v, f, None


def view_directions(n: int, seed: int, name: str) -> np.ndarray:
    """``n`` random unit view directions for mesh ``name`` (seeded by ``seed`` and the name), kept within
    60 deg of the horizon so the object is not seen from straight above or below."""
    rng = np.random.default_rng([seed, sum(name.encode())])
    out = []
    while len(out) < n:
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        if abs(d[1]) < math.sin(math.radians(60)):
            out.append(d)
    return np.array(out)


def baked_grey(vertices, faces) -> np.ndarray:
    """(V, 3) float32 sRGB grey vertex colours of an uncoloured mesh's lighting (``optim.vertex_luminance``
    with the default light): the seeds' pre-lit case."""
    import optim
    import pmetric as pm

    lum = optim.vertex_luminance(vertices, faces)
    g = np.asarray(pm.linear_to_srgb(np.asarray(lum, np.float32)), np.float32)
    return np.repeat(g[:, None], 3, axis=1)


def mesh_specs(cfg: dict) -> list[dict]:
    """[{"name", "kind": "file"|"procedural", "spec"}] of the config's meshes (missing files skipped with
    ``missing_meshes = "skip"``, else PlodError naming them); names made unique."""
    out, seen = [], set()
    for m in cfg["meshes"]:
        p = repo_path(m)
        if not p.is_file():
            if cfg["missing_meshes"] == "skip":
                continue
            raise PlodError(f"config key 'meshes': {m!r} not found (missing_meshes = \"skip\" skips absent files)")
        out.append({"name": p.stem, "kind": "file", "spec": str(p)})
    for s in cfg["procedural"]:
        out.append({"name": s.replace(":", "-"), "kind": "procedural", "spec": s})
    for m in out:
        base, k = m["name"], 2
        while m["name"] in seen:
            m["name"], k = f"{base}_{k}", k + 1
        seen.add(m["name"])
    if not out:
        raise PlodError("experiment: no meshes (none of the config's files exist and 'procedural' is empty)")
    return out


def skipped_meshes(cfg: dict) -> list[str]:
    """The config's mesh files that are absent here (skipped with ``missing_meshes = "skip"``)."""
    return [m for m in cfg["meshes"] if not repo_path(m).is_file()]


def _budget_label(b) -> str:
    """A budget as the rows show it: a fraction with its point (1.0, the whole mesh, is not 1 triangle)."""
    if b is None:
        return "-"
    return (f"{b:.1f}" if float(b).is_integer() else f"{b:g}") if isinstance(b, float) else str(int(b))


def _model_spec(method: str) -> str:
    if method.startswith("model:"):
        return method[len("model:"):]
    return str(repo_path(method))


def cells(cfg: dict, *, git_sha: str = "unknown") -> list[dict]:
    """The sweep's cells in their fixed order: picklable task dicts for :func:`run_cell`."""
    settings = {k: cfg[k] for k in ("tree_method", "object_deg", "gaze_error_deg", "judges", "judge_size")}
    out = []
    for mesh in mesh_specs(cfg):
        for vi, d in enumerate(view_directions(cfg["views"], cfg["seed"], mesh["name"])):
            for g in cfg["gaze_offsets_deg"]:
                for lighting in cfg["lightings"]:
                    for method in cfg["methods"]:
                        for b in (None,) if method == "imperceptible" else cfg["budgets"]:
                            label = method if _method_ok(method) and not method.lower().endswith(".json") \
                                else f"model:{Path(method).stem}"
                            cid = f"{mesh['name']}/v{vi}/g{g:g}/{lighting}/b{_budget_label(b)}/{label}"
                            out.append({"index": len(out), "cell": cid, "mesh": mesh, "view": vi,
                                        "direction": [float(x) for x in d], "gaze_deg": float(g),
                                        "lighting": lighting, "budget": b, "method": method, "label": label,
                                        "settings": settings, "git_sha": git_sha})
    seen = {}
    for t in out:  # rows are keyed by id: two cells of one id would keep one row and drop the other silently
        if t["cell"] in seen:
            raise PlodError(f"config: two cells would share the id {t['cell']!r} (gaze offsets or budgets equal to "
                            "6 significant digits, or two model files of one name); make them distinct")
        seen[t["cell"]] = True
    return out


# ----------------------------------------------------------------------------------------------- the worker
_LOCK = threading.Lock()  # one tree build at a time per worker process (Dask threads share the caches)
_WARM: set = set()  # (mesh, lighting, tree method, method) whose programs this worker has compiled


@functools.lru_cache(maxsize=8)
def _mesh(kind: str, spec: str):
    import optim

    if kind == "procedural":
        v, f, c = procedural_mesh(spec)
    else:
        v, f, c = optim.load_mesh(spec)
    return np.asarray(v, np.float64), np.asarray(f, np.int32), None if c is None else np.asarray(c, np.float32)


@functools.lru_cache(maxsize=8)
def _tree_cached(kind: str, spec: str, lighting: str, method: str):
    """(tree, the original (V, F, C) in the cell's lighting, build seconds) of one mesh, built once."""
    import optim

    v, f, c = _mesh(kind, spec)
    if lighting == "baked" and c is None:
        c = baked_grey(v, f)
    t0 = time.perf_counter()
    tree = optim.build_tree(v, f, c, method=method)
    return tree, (v, f, c), time.perf_counter() - t0


def _tree(kind, spec, lighting, method):
    """:func:`_tree_cached` and whether this call built it."""
    with _LOCK:
        before = _tree_cached.cache_info().misses
        out = _tree_cached(kind, spec, lighting, method)
        return out, _tree_cached.cache_info().misses > before


@functools.lru_cache(maxsize=16)
def _model(spec: str):
    from pmetric import make_model

    return make_model(spec)


@functools.lru_cache(maxsize=1)
def _versions() -> tuple[str, str]:
    from importlib import metadata

    names = ("jax", "numpy", "meshoptimizer", "fast-simplification", "flip-evaluator", "pyfvvdp", "torch")
    parts = []
    for n in names:
        try:
            parts.append(f"{n} {metadata.version(n)}")
        except metadata.PackageNotFoundError:
            pass
    try:
        plod = metadata.version("plod")
    except metadata.PackageNotFoundError:  # pragma: no cover - run from a checkout without install
        plod = "unknown"
    return plod, "; ".join(parts)


def perceptual_distance(tree, pkeys, unfolded) -> float:
    """plod's imperceptible distance of a cut: the largest perceptual key among its folded internal
    nodes (0.0 when none is folded); <= 1 means imperceptible under the model [LHNW00 §4]."""
    internal = tree.internal
    folded = ~np.asarray(unfolded)[internal]
    k = np.asarray(pkeys)[internal][folded]
    return float(k.max()) if k.size else 0.0


def _view(verts, task):
    import optim
    from experiments.judge import offset_gaze_view

    s = task["settings"]
    kw = {"lighting": optim.Lighting()} if task["lighting"] == "relit" else {}
    return offset_gaze_view(verts, task["gaze_deg"], object_deg=s["object_deg"],
                            direction=np.asarray(task["direction"]), gaze_error_deg=s["gaze_error_deg"], **kw)


def _peer(method, v, f, c, target):
    """A view-independent peer's result ``(vertices, faces, colors)`` at ``target`` triangles."""
    from experiments.peers import compact, fast_simplify, meshopt_simplify, nearest_colors

    if method == "meshoptimizer":
        return compact(v, meshopt_simplify(v, f, target, c), c)
    pv, pf = fast_simplify(v, f, target)
    return pv, pf.astype(np.int32), nearest_colors(v, c, pv)


def _simplify(task, times):
    """(result mesh, tree, view, cut or None, target) of one cell; stage seconds added to ``times``."""
    import optim

    m = task["mesh"]
    s = task["settings"]
    (tree, original, build_s), built = _tree(m["kind"], m["spec"], task["lighting"], s["tree_method"])
    times["time_tree_s"] = build_s if built else 0.0
    view = _view(original[0], task)
    method, b = task["method"], task["budget"]

    def timed(stage, fn, *a, **kw):
        t0 = time.perf_counter()
        out = fn(*a, **kw)
        times[stage] = times.get(stage, 0.0) + time.perf_counter() - t0
        return out

    pkeys = timed("time_score_s", optim.score, tree, view)
    if method == "imperceptible":
        cut = timed("time_cut_s", optim.threshold_cut, tree, pkeys, 1.0, monotone="trust")
        return timed("time_extract_s", optim.extract, tree, cut), tree, view, cut, pkeys, None
    T = int(tree.n_triangles)
    n = max(1, int(round(b * T)) if isinstance(b, float) else int(b))
    pcut = timed("time_cut_s", optim.budget_cut, tree, pkeys, n, monotone="trust")
    target = int(pcut.triangles)
    if method == "perceptual":
        return timed("time_extract_s", optim.extract, tree, pcut), tree, view, pcut, pkeys, target
    if method in PEERS:
        return timed("time_peer_s", _peer, method, *original, target), tree, view, None, pkeys, target
    if method in ("size", "geometric"):
        keys = timed("time_score_s", optim.score, tree, view, None, method)
    else:
        keys = timed("time_score_s", optim.score, tree, view, _model(_model_spec(method)))
    cut = timed("time_cut_s", optim.budget_cut, tree, keys, target, monotone="trust")
    return timed("time_extract_s", optim.extract, tree, cut), tree, view, cut, pkeys, target


def run_cell(task: dict, *, keep: bool = False) -> dict:
    """Run one cell (a task of :func:`cells`): its row (:data:`COLUMNS`). A failure is recorded in the
    row's ``error`` (``"Type: message"``), never raised. ``keep``: also return the judgement with its
    maps under ``"_judgement"`` (for the report's examples)."""
    import optim

    t_cell = time.perf_counter()
    plod, vers = _versions()
    m = task["mesh"]
    d = task["direction"]
    row = {k: None for k in COLUMNS}
    row.update(index=task["index"], cell=task["cell"], mesh=m["name"], view=task["view"], dir_x=d[0], dir_y=d[1],
               dir_z=d[2], gaze_deg=task["gaze_deg"], lighting=task["lighting"], budget=_budget_label(task["budget"]),
               method=task["label"], worker=f"{os.uname().nodename}:{os.getpid()}:{threading.get_ident()}",
               plod_version=plod, git_sha=task["git_sha"], versions=vers)
    times = {k: 0.0 for k in TIME_COLUMNS}
    try:
        warm = (m["kind"], m["spec"], task["lighting"], task["settings"]["tree_method"], task["method"])
        if warm not in _WARM:  # the first cell of a kind on this worker compiles its XLA programs: not timed
            t0 = time.perf_counter()
            _simplify(task, times)
            times = {**{k: 0.0 for k in TIME_COLUMNS}, "time_tree_s": times["time_tree_s"]}
            times["time_warmup_s"] = time.perf_counter() - t0 - times["time_tree_s"]
            _WARM.add(warm)
        tree_s = times["time_tree_s"]
        result, tree, view, cut, pkeys, target = _simplify(task, times)
        times["time_tree_s"] += tree_s  # the build, if this cell's warm-up or run did it
        row.update(input_triangles=int(tree.n_triangles), target_triangles=target, triangles=int(len(result[1])))
        judges = task["settings"]["judges"]
        if "distance" in judges and cut is not None:
            row["distance"] = perceptual_distance(tree, pkeys, cut.unfolded)
        images = tuple(j for j in ("fovvdp", "flip") if j in judges)
        if images:
            from experiments.judge import judge

            s = task["settings"]
            (_, original, _), _ = _tree(m["kind"], m["spec"], task["lighting"], s["tree_method"])
            t0 = time.perf_counter()
            res = judge(original, result, view, mode=task["lighting"],
                        lighting=optim.Lighting() if task["lighting"] == "relit" else None,
                        size=tuple(s["judge_size"]), metrics=images, heatmap=keep)
            times["time_judge_s"] = time.perf_counter() - t0
            row.update(jod=None if res.jod is None else float(res.jod),
                       flip=None if res.flip_mean is None else float(res.flip_mean))
            if keep:
                row["_judgement"] = res
    except Exception as exc:  # a failed cell records its error; the sweep goes on
        row["error"] = f"{type(exc).__name__}: {' '.join(str(exc).split())}"
    times["time_cell_s"] = time.perf_counter() - t_cell
    row.update(times)
    return row


# ----------------------------------------------------------------------------------------------- the sweep
def _read_journal(path: Path) -> list[dict]:
    """The complete rows of a journal (a line cut short by a kill is dropped)."""
    rows = []
    if not path.is_file():
        return rows
    for line in path.read_text(encoding="utf-8", errors="replace").splitlines(keepends=True):
        if not line.endswith("\n"):
            break
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(row, dict) and isinstance(row.get("cell"), str) and isinstance(row.get("index"), int):
            rows.append(row)  # anything else is not a row of ours (a damaged line): its cell runs again
    return rows


def _saved_sweep(saved: Path):
    """The sweep recorded in ``saved`` (experiment.json), or PlodError naming the file."""
    try:
        doc = json.loads(saved.read_text(encoding="utf-8"))
        return doc["sweep"]
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError, IndexError):
        raise PlodError(f"--resume: {saved} is not a sweep record of plod experiment (damaged?); use another "
                        "--out or run without --resume") from None


def _sweep_config(cfg: dict) -> dict:
    return json.loads(json.dumps({k: cfg[k] for k in SWEEP_KEYS}))


def _execute(tasks, workers: int, scheduler, on_row) -> None:
    """Run ``tasks`` (local processes, in this process with 0 workers, or on the Dask cluster at
    ``scheduler``), calling ``on_row(row)`` in this process as each finishes."""
    if not tasks:
        return
    if scheduler:
        try:
            from dask.distributed import Client, as_completed
        except ImportError:
            raise PlodError("--scheduler needs dask.distributed: pip install 'dask[distributed]'") from None
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as exc:
            raise PlodError(f"--scheduler {scheduler!r}: cannot connect ({exc})") from None
        try:
            futures = [client.submit(run_cell, t, pure=False) for t in tasks]
            for fut in as_completed(futures):
                on_row(fut.result())
        finally:
            client.close()
        return
    if workers == 0:
        for t in tasks:
            on_row(run_cell(t))
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed as done

    ex = ProcessPoolExecutor(max_workers=min(workers, len(tasks)), mp_context=mp.get_context("spawn"))
    try:
        for fut in done([ex.submit(run_cell, t) for t in tasks]):
            on_row(fut.result())
    finally:
        ex.shutdown(wait=True, cancel_futures=True)


def write_table(rows: list[dict], out: Path) -> Path:
    """``out/results.parquet`` (pyarrow) or ``out/results.csv`` of ``rows`` in :data:`COLUMNS` order,
    written atomically; returns the path."""
    import pmetric as pm

    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        pa = None
    if pa is not None:  # pragma: no cover - pyarrow is not installed here
        path = out / "results.parquet"
        table = pa.Table.from_pylist([{k: r.get(k) for k in COLUMNS} for r in rows])
        with pm.atomic_path(path) as tmp:
            pq.write_table(table, tmp)
        return path
    import csv
    import io

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=COLUMNS, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: "" if r.get(k) is None else r.get(k) for k in COLUMNS})
    path = out / "results.csv"
    atomic_write_text(path, buf.getvalue())
    return path


def read_table(path: str | Path) -> list[dict]:
    """The rows of a results table written by :func:`write_table` (parquet or CSV), typed as the rows."""
    path = Path(path)
    if path.suffix == ".parquet":  # pragma: no cover - pyarrow is not installed here
        import pyarrow.parquet as pq

        return pq.read_table(path).to_pylist()
    import csv

    ints = {"index", "view", "target_triangles", "input_triangles", "triangles"}
    strs = {"cell", "mesh", "lighting", "budget", "method", "error", "worker", "plod_version", "git_sha", "versions"}
    rows = []
    with open(path, newline="", encoding="utf-8") as fh:
        for r in csv.DictReader(fh):
            rows.append({k: (None if v == "" else v if k in strs else int(v) if k in ints else float(v))
                         for k, v in r.items()})
    return rows


def run_experiment(cfg: dict, *, out: str | Path | None = None, workers: int = 1, scheduler=None,
                   resume: bool = False, progress: Callable[[str, int, int], None] | None = None,
                   config: str | Path | None = None) -> list[dict]:
    """Run (or, with ``resume``, finish) the sweep of the resolved config ``cfg``; returns its rows in cell
    order and writes the journal and the results table into ``out`` (default ``cfg["out"]``).

    ``workers``: local processes (0: this process); ``scheduler``: a Dask scheduler address (or anything
    ``dask.distributed.Client`` takes), used instead. ``progress(cell id, done, total)``: per finished cell.
    A resumed run refuses a config whose sweep differs from the interrupted one's (PlodError); ``config``
    (the file ``cfg`` was read from) must not lie in ``out`` under a name the run writes (:data:`WRITES`).
    """
    from experiments._runinfo import git_sha

    out = check_out_dir(repo_path(out if out is not None else cfg["out"]), config=config, writes=WRITES)
    if not isinstance(workers, int) or workers < 0:
        raise PlodError(f"--workers must be an integer >= 0, got {workers!r}")
    if out.exists() and not out.is_dir():
        raise PlodError(f"--out {str(out)!r} is a file; give a folder")
    # every cell (its meshes found, its id unique) before anything in ``out`` is touched: a config error
    # must not empty the journal of the run already there
    tasks = cells(cfg, git_sha=git_sha())
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise PlodError(f"--out {str(out)!r}: cannot make the folder ({exc.strerror or exc})") from None
    journal, saved = out / "results.jsonl", out / "experiment.json"
    sweep = _sweep_config(cfg)
    done: dict[str, dict] = {}
    if resume and journal.exists():
        if saved.is_file() and _saved_sweep(saved) != sweep:
            raise PlodError(f"--resume: the config's sweep differs from the one in {saved}; use another --out "
                            "or run without --resume")
        rows = _read_journal(journal)
        done = {r["cell"]: r for r in rows if not r.get("error")}
        # rewrite without a line cut short by a kill (and without failed cells: they run again)
        atomic_write_text(journal, "".join(json.dumps(r) + "\n" for r in done.values()))
    else:
        atomic_write_text(journal, "")
    atomic_write_text(saved, json.dumps({"sweep": sweep}, indent=1) + "\n")
    ids = {t["cell"] for t in tasks}
    done = {k: v for k, v in done.items() if k in ids}
    todo = [t for t in tasks if t["cell"] not in done]
    count = [len(done)]
    if progress is not None:
        progress("resumed" if done else "start", count[0], len(tasks))
    with open(journal, "a", encoding="utf-8") as fh:
        def on_row(row):
            fh.write(json.dumps(row) + "\n")
            fh.flush()
            os.fsync(fh.fileno())
            done[row["cell"]] = row
            count[0] += 1
            if progress is not None:
                progress(row["cell"], count[0], len(tasks))

        _execute(todo, workers, scheduler, on_row)
    rows = sorted(done.values(), key=lambda r: r["index"])
    write_table(rows, out)
    return rows


def pareto_front(x, y) -> np.ndarray:
    """Indices of the points not dominated in (x lower, y lower), sorted by x: a point is on the front
    when no other has both x <= and y <= with one strictly less (ties kept once, first index)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    order = np.lexsort((y, x))
    front, best = [], math.inf
    for i in order:
        if y[i] < best:
            front.append(int(i))
            best = y[i]
    return np.array(front, dtype=int)


def strip_volatile(rows) -> list[dict]:
    """The rows without what differs between equal runs (timings, worker) for comparisons."""
    return [{k: v for k, v in r.items() if k not in VOLATILE and not k.startswith("_")} for r in rows]


def main(argv=None) -> int:
    """``python -m experiments.experiment``: the same as ``plod experiment``."""
    import argparse

    from experiments import _cmd_experiment

    parser = argparse.ArgumentParser(prog="plod")
    _cmd_experiment.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["experiment", *(sys.argv[1:] if argv is None else argv)])
    return args.func(args)


if __name__ == "__main__":  # pragma: no cover
    from experiments._runinfo import report_errors

    sys.exit(report_errors(main, "plod experiment"))
