"""Issue 10 experiment: budget-cut priorities from pooled suprathreshold error instead of the
imperceptible distance. Relit (and baked) cells with face culling on, on meshes the tests and the
accuracy sweep do not use (cow, stanford-bunny, turbineblade, a procedural sphere of another size).

A budget cut's greedy order today is the fold's imperceptible distance k (a viewing-distance
multiple; for a change at its falling limb k = 2 theta f_T(c, e), roughly the node's size times a
slowly varying contrast factor), so it spends the budget much like size keys. A judge pools error over
the image: a fold's share is about its area times a power of its threshold ratio
r = c S(max(1/(2 theta), f_peak(e)), e), and its cost is the triangles its unfolding adds. Variants:

    pool{b}:     r^b * A / cost  (A = theta^2 deg2; silhouette folds: band * theta)
    poolnc{b}:   r^b * A
then made monotone (max over descendants) and cut with optim.visible_budget_cut.

    OMP_NUM_THREADS=1 .venv/bin/python reports/accuracy/scripts/pooled_priority.py OUT.jsonl [meshes]
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import optim  # noqa: E402
from experiments.accuracy import DEFAULTS, PEERS, _Mesh, _view, plod_mesh  # noqa: E402
from experiments.experiment import procedural_mesh, view_directions  # noqa: E402
from experiments.judge import judge  # noqa: E402


def ratio_and_area(tree, view, model):
    t = optim.node_terms(tree, view)
    theta = np.asarray(t.theta, np.float64)
    ecc = np.asarray(t.eccentricity, np.float64)
    c = np.asarray(t.contrast, np.float64)
    f = 1.0 / (2.0 * np.maximum(theta, 1e-9))

    @jax.jit
    def sens(f, e):
        fp = model.peak_frequency(e)
        return model.sensitivity(jnp.maximum(f, fp), e)

    s = np.asarray(sens(jnp.asarray(f, jnp.float32), jnp.asarray(ecc, jnp.float32)), np.float64)
    r = c * s
    area = np.where(t.silhouette, np.asarray(t.band_deg, np.float64) * theta, theta * theta)
    dead = t.culled | (theta <= 0)
    return r, area, dead


def priorities(tree, view, model, variants):
    r, area, dead = ratio_and_area(tree, view, model)
    cost = np.maximum(np.asarray(tree.num_subtris, np.float64), 1.0)
    out = {}
    for name in variants:
        if name.startswith("poolnc"):
            b = float(name[6:])
            p = r ** b * area
        elif name.startswith("pool"):
            b = float(name[4:])
            p = r ** b * area / cost
        else:
            raise ValueError(name)
        p = np.where(dead, 0.0, p)
        p = np.log1p(p)  # a monotone transform keeps the order; float32-safe range
        out[name] = optim.repair_monotone(tree, p.astype(np.float32))
    return out


HELD_OUT = ["cow.obj", "stanford-bunny.obj", "turbineblade.ply", "sphere:5:7"]  # in no test and not in the sweep
SIZE = (960, 540)


def held_out_mesh(name):
    """The sweep's :class:`experiments.accuracy._Mesh` of a ../shared mesh file or a procedural spec."""
    v, f, c = procedural_mesh(name) if ":" in name else optim.load_mesh(ROOT.parent / "shared/data/meshes" / name)
    return _Mesh(name, v, f, c)


def judge_fn(mesh, view, lighting):
    """JOD (4 decimals) of a result against the cell's original, as the sweep judges it."""
    light = optim.Lighting() if lighting == "relit" else None
    ref = mesh.original(lighting)
    return lambda res: round(judge(ref, res, view, mode=lighting, lighting=light, size=SIZE, heatmap=False).jod, 4)


def budget_row(tree, view, cfg, b, J, **head):
    """``(row, target)``: today's perceptual budget cut at ``b`` of the input (face culled per ``cfg``) and
    plod's size and geometric keys at its drawn count ``target``, judged by ``J``; ``head`` leads the row."""
    pres, _ = plod_mesh(tree, optim.score(tree, view), view, cfg, max(int(b * tree.n_triangles), 1))
    target = len(pres[1])
    row = dict(head, budget=b, tris=target, perceptual=J(pres))
    for metric in ("size", "geometric"):
        row[metric] = J(plod_mesh(tree, optim.score(tree, view, None, metric), view, cfg, target)[0])
    return row, target


def held_out_cells(names, cfg):
    """Yield ``(name, mesh, view, gaze, J)`` over the held-out cells: each mesh of ``names``, one random
    view, gaze 0 and 8 deg, relit, with its judge ``J``."""
    for name in names:
        mesh = held_out_mesh(name)
        for d in view_directions(1, 77, name):
            for g in (0.0, 8.0):
                view = _view(mesh, d, g, "relit", cfg, True)
                yield name, mesh, view, g, judge_fn(mesh, view, "relit")


def budget_rows(out, tree, view, cfg, J, variants, **head):
    """Emit one row per budget (3, 8, 20 %): :func:`budget_row` plus ``row[label] = J(make(target))``
    for each ``label: make`` of ``variants`` (``make(target)`` -> the variant's mesh at the drawn count)."""
    for b in (0.03, 0.08, 0.2):
        t0 = time.perf_counter()
        row, target = budget_row(tree, view, cfg, b, J, **head)
        for label, make in variants.items():
            row[label] = J(make(target))
        row["s"] = round(time.perf_counter() - t0, 1)
        emit(out, row)


def emit(out, row):
    print(json.dumps(row), flush=True)
    out.write(json.dumps(row) + "\n")
    out.flush()


def main():
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 else HELD_OUT
    variants = ["pool1", "pool2", "pool3", "poolnc2"]
    cfg = dict(DEFAULTS, face_cull=True, size=list(SIZE))
    model = optim.default_model()
    for name in names:
        mesh = held_out_mesh(name)
        tree = mesh.tree["relit"]
        for d in view_directions(1, 77, name):
            for g in (0.0, 8.0):
                view = _view(mesh, d, g, "relit", cfg, True)
                J = judge_fn(mesh, view, "relit")
                pr = priorities(tree, view, model, variants)
                for b in (0.03, 0.08, 0.2):
                    t0 = time.perf_counter()
                    row, target = budget_row(tree, view, cfg, b, J, mesh=name, gaze=g, lighting="relit")
                    for vn, keys in pr.items():
                        m, _ = plod_mesh(tree, keys, view, cfg, target)
                        row[vn] = J(m)
                        row[vn + "_tris"] = len(m[1])
                    for peer in PEERS:
                        row[peer] = J(mesh.peer(peer, "relit", target))
                    row["s"] = round(time.perf_counter() - t0, 1)
                    emit(out, row)


if __name__ == "__main__":
    main()
