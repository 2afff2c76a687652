"""Issue 10 experiment: does the budget cut's order gain from another eccentricity, or another silhouette
band width, in its keys?

Today a node's eccentricity is the angle from the gaze to the node's nearest point less the gaze
error (a bound, needed by the imperceptible test). A budget cut only needs an order, so it may use a
typical value instead: the angle to the node's centre (``ctr``), without the gaze error (``ctr0``), or
the eccentricity scaled (``x1.5``: a steeper fall-off than the model's). ``band0.5`` etc.: the band a
silhouette fold can change (today the projected slab, a bound) scaled, i.e. silhouette folds weighed
less or more against interior ones. Budget keys only; relit, face
culling on, on meshes the tests and the sweep do not use. JOD of each variant's cut at the drawn count
of today's perceptual cut.

    OMP_NUM_THREADS=1 .venv/bin/python reports/accuracy/scripts/budget_eccentricity.py OUT.jsonl [meshes] [variants]
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import optim  # noqa: E402
import optim._score as S  # noqa: E402
import optim._terms as T  # noqa: E402
from pooled_priority import HELD_OUT, SIZE, budget_rows, held_out_cells  # noqa: E402
from experiments.accuracy import DEFAULTS, plod_mesh  # noqa: E402

_today = T.eccentricity
_today_band = T.band_width


def _band(scale):
    def band(ch, vp, g, theta):
        return jnp.minimum(scale * _today_band(ch, vp, g, theta), theta)
    return band


def _variant(name):
    def ecc(vp, g, theta):
        kx, ky, gaze_err = vp.scal[6], vp.scal[7], vp.scal[8]
        front_pt, eye_vec = T._image(vp, g)
        ang = None
        for k in range(vp.gaze.shape[0]):
            a_k = T._angle_deg(eye_vec, (vp.gaze[k, 0] * kx, vp.gaze[k, 1] * ky, 1.0))
            ang = a_k if ang is None else jnp.minimum(ang, a_k)
        if name == "ctr":
            e = jnp.maximum(ang - gaze_err, 0.0)
        elif name == "ctr0":
            e = ang
        elif name.startswith("x"):
            e = float(name[1:]) * jnp.maximum(ang - 0.5 * theta - gaze_err, 0.0)
        else:
            raise ValueError(name)
        return jnp.where(front_pt & ~g.inside, e, 0.0)
    return ecc


def keys_with(name, tree, view):
    if name.startswith("band"):
        T.band_width = S.band_width = _band(float(name[4:]))
    else:
        T.eccentricity = S.eccentricity = _variant(name)
    jax.clear_caches()
    try:
        return optim.score(tree, view)
    finally:
        T.eccentricity = S.eccentricity = _today
        T.band_width = S.band_width = _today_band
        jax.clear_caches()


VARIANTS = ("ctr", "ctr0", "x1.5", "x0.7")


def main():
    out = open(sys.argv[1], "a")
    names = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else HELD_OUT
    variants = sys.argv[3].split(",") if len(sys.argv) > 3 else VARIANTS
    cfg = dict(DEFAULTS, face_cull=True, size=list(SIZE))
    for name, mesh, view, g, J in held_out_cells(names, cfg):
        tree = mesh.tree["relit"]
        base = optim.score(tree, view)
        ks = {v: keys_with(v, tree, view) for v in variants}
        for v, k in ks.items():
            assert (k != base).any(), v
        budget_rows(out, tree, view, cfg, J,
                    {v: (lambda t, k=k: plod_mesh(tree, k, view, cfg, t)[0]) for v, k in ks.items()},
                    mesh=name, gaze=g)

if __name__ == "__main__":
    main()
