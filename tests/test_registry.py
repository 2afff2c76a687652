"""pmetric's one model table: make_model's spellings, compositions and files, the default model,
unknown names, ``plod models`` and the ``--model`` flags of ``plod simplify`` / ``plod fit``."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

import optim
import pmetric
from experiments.cli import main
from pmetric import PlodError, make_model


@pytest.mark.parametrize("cls, spellings", [
    ("KellyAbstract", ["KellyAbstract", "kellyabstract", "kelly-abstract", "kelly_abstract", "KELLY ABSTRACT"]),
    ("StelaCSF", ["StelaCSF", "stela", "stelacsf", "Stela-CSF"]),
    ("Barten", ["Barten", "barten"]),
    ("ManosSakrison", ["ManosSakrison", "manos", "manossakrison", "manos-sakrison"]),
    ("KellySpatioTemporal", ["KellySpatioTemporal", "kellyspatiotemporal", "kelly_spatio_temporal"]),
    ("ReddyAcuity", ["ReddyAcuity", "reddy", "reddyacuity"]),
])
def test_every_spelling_gives_the_same_class(cls, spellings):
    models = [make_model(s) for s in spellings]
    assert {type(m).__name__ for m in models} == {cls}
    # the same default constants whatever the spelling
    leaves = [np.concatenate([np.ravel(x) for x in __import__("jax").tree_util.tree_leaves(m)]) for m in models]
    for x in leaves[1:]:
        np.testing.assert_array_equal(x, leaves[0])


def test_default_model_is_one_name():
    assert pmetric.DEFAULT_MODEL == "stela"
    for m in (pmetric.default_model(), optim.default_model(), make_model(None), make_model("default")):
        assert type(m) is pmetric.StelaCSF
    # the published constants [MAC22] (not a refit)
    for a, b in zip(jax.tree_util.tree_leaves(pmetric.default_model()), jax.tree_util.tree_leaves(pmetric.StelaCSF())):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    inst = pmetric.ManosSakrison(peak_sensitivity=123.0)
    assert make_model(inst) is inst  # an instance comes back as is


@pytest.mark.parametrize("spec, inner", [
    ("eccentric", "ManosSakrison"),
    ("eccentric(manossakrison)", "ManosSakrison"),
    ("Eccentric:ManosSakrison", "ManosSakrison"),
    ("Eccentric( manos )", "ManosSakrison"),
    ("eccentric:kellyst", "KellySpatioTemporal"),
    ("eccentric(barten)", "Barten"),
])
def test_compositions(spec, inner):
    m = make_model(spec)
    assert type(m) is pmetric.Eccentric and type(m.csf).__name__ == inner
    assert type(m.magnification) is pmetric.RovamoVirsu


@pytest.mark.parametrize("spec, msg", [
    ("eccentric(kellyabstract)", "already depends on eccentricity"),
    ("kellyabstract(manos)", "wraps no other model"),
    ("eccentric()", "empty inner model"),
    ("eccentric(nobody)", "unknown model 'nobody'"),
    ("display", "not a CSF model"),
    ("calibratedcsf", "cannot be built from its name"),
    ("missing.json", "model file not found"),
])
def test_bad_specs(spec, msg):
    with pytest.raises(PlodError, match=msg.replace("(", r"\(").replace(")", r"\)")):
        make_model(spec)


def test_unknown_name_lists_names_and_suggests():
    with pytest.raises(PlodError) as exc:
        make_model("kelyabstract")
    msg = str(exc.value)
    assert "unknown model 'kelyabstract'" in msg and "did you mean KellyAbstract?" in msg
    assert "\n" not in msg
    for name in ("Barten", "StelaCSF", "ManosSakrison", "Eccentric(CSF)", ".json"):
        assert name in msg
    assert isinstance(exc.value, ValueError)
    with pytest.raises(PlodError, match="unknown model 'zzzz'; choose one of"):
        make_model("zzzz")


def test_fitted_json_round_trip(tmp_path):
    m = pmetric.Eccentric(pmetric.ManosSakrison(peak_sensitivity=321.0))
    p = pmetric.save_model(m, tmp_path / "fitted.json")
    for spec in (p, str(p), f"eccentric:{tmp_path / 'mine.json'}", f"eccentric({tmp_path / 'mine.json'})"):
        if "mine" in str(spec):
            pmetric.save_model(pmetric.ManosSakrison(peak_sensitivity=99.0), tmp_path / "mine.json")
        back = make_model(spec)
        assert type(back) is pmetric.Eccentric
    assert float(make_model(p).csf.peak_sensitivity) == 321.0
    assert float(back.csf.peak_sensitivity) == 99.0
    pmetric.save_model(pmetric.Display.default(), tmp_path / "display.json")
    with pytest.raises(PlodError, match="not a CSF model"):
        make_model(tmp_path / "display.json")


def test_entries_know_inputs_and_constants():
    entries = pmetric.model_entries()
    assert set(entries) == set(pmetric.model_registry())
    ka = entries["KellyAbstract"]
    assert ka.inputs() == ("f", "e") and set(ka.constants()) == {"delta", "f0"}
    assert entries["Eccentric"].wraps == "ManosSakrison"
    assert "csf.peak_sensitivity" in entries["Eccentric"].constants()
    assert entries["CalibratedCSF"].constants() is None  # needs arguments
    assert "stela" in entries["StelaCSF"].aliases


def test_plod_models_json(capsys):
    assert main(["models", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    csf = {n for n, c in pmetric.model_registry().items() if issubclass(c, pmetric.CSFModel)}
    assert csf <= set(rows)
    for name in csf:
        r = rows[name]
        assert r["kind"] == "csf" and isinstance(r["inputs"], list) and "f" in r["inputs"], name
        assert r["constants"] is None or all(isinstance(k, str) for k in r["constants"]), name
    assert rows["StelaCSF"]["default"] and not rows["KellyAbstract"]["default"]
    assert rows["KellyAbstract"]["constants"]["f0"] == 4.0
    assert rows["StelaCSF"]["inputs"] == list(pmetric.StelaCSF.inputs)
    assert {"f", "e", "v", "luminance", "area"} <= set(rows["StelaCSF"]["inputs"])
    assert main(["models"]) == 0
    out = capsys.readouterr().out
    assert "kellyabstract" in out and "(default)" in out and "delta=369.453" in out


def test_simplify_and_fit_accept_any_spelling(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("PLOD_CACHE", str(tmp_path / "cache"))
    v, f = optim.icosphere(1)
    mesh = optim.save_mesh(tmp_path / "tiny.obj", v, f)
    for spelling in ("kellyabstract", "KellyAbstract", "eccentric(manos)"):
        assert main(["simplify", str(mesh), "--budget", "20", "--method", "octree", "--json"]) == 0
        capsys.readouterr()
        assert main(["simplify", str(mesh), "--budget", "20", "--method", "octree", "--json",
                     "--model", spelling]) == 0
        assert json.loads(capsys.readouterr().out)["model"] == type(make_model(spelling)).__name__
    csv = tmp_path / "cal.csv"
    freqs = np.geomspace(0.5, 20, 8)
    logc = np.log10(1.0 / np.asarray(pmetric.KellyAbstract(delta=300.0).sensitivity(freqs)))
    csv.write_text("s_frequency,log_cone_contrast\n" + "".join(f"{a},{b}\n" for a, b in zip(freqs, logc)))
    assert main(["fit", str(csv), "--model", "KellyAbstract", "--fit", "delta", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["model"] == "KellyAbstract"
    assert report["params"]["delta"]["value"] == pytest.approx(300.0, rel=1e-3)
    assert main(["fit", str(csv), "--model", "kelyabstract"]) == 2
    err = capsys.readouterr().err
    assert "did you mean KellyAbstract?" in err and err.count("\n") == 1


def test_registered_class_is_buildable_by_name_and_alias(tmp_path):
    import jax.numpy as jnp

    class Flat(pmetric.CSFModel):
        gain: object = None

        def __init__(self, gain=7.0):
            self.gain = jnp.asarray(gain, jnp.float32)

        def sensitivity(self, f, e=0.0, v=0.0):
            return self.gain * jnp.ones_like(jnp.asarray(f))

    pmetric.register_model(Flat, aliases=("flat-csf", "constant"))
    try:
        for spelling in ("Flat", "flat", "FLAT_CSF", "constant"):
            assert type(make_model(spelling)) is Flat
        assert pmetric.model_entries()["Flat"].constants() == {"gain": 7.0}
        back = make_model(pmetric.save_model(Flat(3.0), tmp_path / "flat.json"))
        assert float(back.gain) == 3.0
    finally:
        pmetric._registry._EXTRA.pop("Flat", None)
    with pytest.raises(PlodError, match="unknown model 'flat'"):
        make_model("flat")
