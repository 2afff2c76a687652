"""How far "adding a criterion never adds triangles" holds, on random scenes (issue 12's test).

Per scene: a fractal grid of 33, 65 or 129 samples, a random camera (position, heading, pitch, field of view
60-200 x 40-135 deg, gaze up to 30 deg off), xi from 0.5 to 8 cycles/deg and one previous camera a random
step away; all 16 combinations of size, periphery, velocity and cull. For every pair (mask, mask + one
criterion) it counts the pairs where the added criterion adds triangles, and checks the two properties the
refinement guarantees (tests/test_terrain.py asserts them on fewer scenes):

- the restricted split sets are nested (the added criterion only removes splits);
- the triangles added are at most those of the drawn leaves, under the added criterion, whose bounding
  sphere is not wholly inside the field of view when both refinements cull (the only place the finer
  one can draw less: there its children can all be culled while the unsplit leaf is not), none otherwise.

    .venv/bin/python reports/terrain/scripts/monotone.py [--scenes 300] [--seed 0] [--split-view-edge]

``--split-view-edge``: the same scenes refined with ``TerrainCriteria(split_view_edge=True)`` (the squares the
view's edge crosses split to the finest level), where no criterion may add a triangle.
"""
import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))
from optim._terrain import (Heightfield, TerrainCamera, TerrainCriteria, fractal_heightfield,  # noqa: E402
                            refine_terrain, straddle_triangles)

NAMES = ("size", "periphery", "velocity", "cull")


def scene(rng, sizes=(33, 65, 129)):
    n = int(rng.choice(sizes))
    sp = float(rng.uniform(1.0, 10.0))
    hf = Heightfield(fractal_heightfield(n, seed=int(rng.integers(1 << 30)), relief=float(rng.uniform(5, 80)) * sp),
                     sp)
    side = (n - 1) * sp
    eye = np.array([rng.uniform(-0.2, 1.2) * side, float(hf.heights.max()) + rng.uniform(0.02, 0.5) * side,
                    rng.uniform(-0.2, 1.2) * side])
    yaw, pitch = rng.uniform(0, 2 * np.pi), rng.uniform(-0.8, 0.0)
    fwd = np.array([np.sin(yaw) * np.cos(pitch), np.sin(pitch), np.cos(yaw) * np.cos(pitch)])
    fov = (float(rng.uniform(60, 200)), float(rng.uniform(40, 135)))
    gaze = (float(rng.uniform(-30, 30)), float(rng.uniform(-20, 20)))
    cam = TerrainCamera(eye, fwd, fov_deg=fov, gaze_deg=gaze)
    prev = TerrainCamera(eye - rng.normal(0, 0.02 * side, 3), fwd + rng.normal(0, 0.05, 3), fov_deg=fov)
    return hf, cam, (prev,), float(np.exp(rng.uniform(np.log(0.5), np.log(8.0))))


def check(hf, cam, prev, xi, edge=False):
    """(pairs, [(mask, added criterion, triangles added, bound)] where > 0); asserts the two properties.
    ``edge``: with ``TerrainCriteria(split_view_edge=True)``, whose bound is 0 (no criterion adds)."""
    lods = {}
    for mask in range(16):
        on = {k: bool(mask >> b & 1) for b, k in enumerate(NAMES)}
        lods[mask] = refine_terrain(hf, cam, TerrainCriteria(xi=xi, split_view_edge=edge, **on), prev)
    pairs, worse = 0, []
    for mask in range(16):
        for b in range(4):
            if mask >> b & 1:
                continue
            fine, coarse = lods[mask], lods[mask | 1 << b]
            pairs += 1
            for sf, sc in zip(fine.split, coarse.split):
                assert not (sc & ~sf).any(), (mask, NAMES[b], "split sets not nested")
            added = coarse.triangles - fine.triangles
            if added > 0:  # only where both have cull: without it in the finer one, it draws every leaf
                bound = straddle_triangles(hf, cam, coarse) if mask >> 3 & 1 and not edge else 0
                assert added <= bound, (mask, NAMES[b], added, bound)
                worse.append((mask, NAMES[b], added, bound))
    return pairs, worse


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=300)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--split-view-edge", action="store_true", help="refine with TerrainCriteria(split_view_edge=True)")
    a = ap.parse_args()
    rng = np.random.default_rng(a.seed)
    pairs, worse, scenes_hit = 0, [], 0
    for _ in range(a.scenes):
        p, w = check(*scene(rng), edge=a.split_view_edge)
        pairs += p
        worse += w
        scenes_hit += bool(w)
    added = np.array([w[2] for w in worse]) if worse else np.zeros(0, int)
    by = {k: sum(1 for w in worse if w[1] == k) for k in NAMES}
    print(f"{'split_view_edge: ' if a.split_view_edge else ''}{a.scenes} scenes, {pairs} pairs (mask, mask + one criterion): split sets nested in all; "
          f"a criterion added triangles in {len(worse)} pairs ({scenes_hit} scenes), "
          f"worst +{int(added.max()) if len(added) else 0}, median +{int(np.median(added)) if len(added) else 0}; "
          f"by added criterion {by}; every excess within the straddling leaves' triangles "
          f"(largest share of that bound {max((w[2] / w[3] for w in worse), default=0):.3f})")


if __name__ == "__main__":
    main()
