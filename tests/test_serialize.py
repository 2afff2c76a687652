"""Tests for pmetric.save_model / load_model (JSON round trips of every pmetric model)."""

from __future__ import annotations

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import pmetric
from pmetric import CalibratedCSF, CSFModel, load_model, save_model

F = jnp.array([0.5, 2.0, 8.0, 20.0])
E = jnp.array([0.0, 5.0, 0.0, 20.0])
V = jnp.array([0.0, 1.0, 4.0, 0.5])


def _instances() -> dict[str, eqx.Module]:
    """One instance of every registered class (default constructor where there is one)."""
    special = {
        "Eccentric": lambda: pmetric.Eccentric(pmetric.ManosSakrison(), pmetric.RovamoVirsu()),
        "CalibratedCSF": lambda: CalibratedCSF([1.0, 4.0, 16.0], [0.0, 10.0],
                                               np.array([[-2.0, -1.5], [-2.3, -1.7], [-1.0, -0.5]])),
        "Display": pmetric.Display.default,
    }
    out = {}
    for name, cls in pmetric.model_registry().items():
        if name in special:
            out[name] = special[name]()
            continue
        try:
            out[name] = cls()
        except TypeError:
            continue  # needs arguments: covered by `special` or a dedicated test
    return out


def _equal(a, b):
    la, ta = jax.tree_util.tree_flatten(a)
    lb, tb = jax.tree_util.tree_flatten(b)
    assert ta == tb  # same classes and static fields
    for x, y in zip(la, lb):
        assert x.dtype == y.dtype and x.shape == y.shape
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_registry_contents():
    reg = pmetric.model_registry()
    for name in ("ManosSakrison", "KellyAbstract", "Eccentric", "RovamoVirsu", "CalibratedCSF", "Display"):
        assert name in reg, name
    assert "CSFModel" not in reg  # abstract
    # every concrete CSFModel exported by pmetric is registered
    for name, obj in vars(pmetric).items():
        if isinstance(obj, type) and issubclass(obj, CSFModel) and obj is not CSFModel:
            assert reg[name] is obj


def test_round_trip_every_model(tmp_path, dtype):
    inst = _instances()
    assert {"ManosSakrison", "Eccentric", "CalibratedCSF", "Display"} <= set(inst)
    for name, m in inst.items():
        p = save_model(m, tmp_path / f"{name}.json")
        m2 = load_model(p)
        assert type(m2) is type(m)
        _equal(m, m2)
        if isinstance(m, CSFModel):
            s1, s2 = m.sensitivity(F, E, V), m2.sensitivity(F, E, V)
            np.testing.assert_array_equal(np.asarray(s1), np.asarray(s2), err_msg=name)
            # the loaded model is a working pytree under jit
            s3 = eqx.filter_jit(lambda mm: mm.sensitivity(F, E, V))(m2)
            np.testing.assert_allclose(s3, s1, rtol=1e-5, err_msg=name)
    d2 = load_model(tmp_path / "Display.json")
    np.testing.assert_array_equal(d2.luminance(jnp.array([0.3, 0.6, 0.9])),
                                  inst["Display"].luminance(jnp.array([0.3, 0.6, 0.9])))
    assert [q for q in tmp_path.iterdir() if q.name.startswith(".")] == []  # no temp files left


def test_static_fields_and_nesting(tmp_path):
    m = CalibratedCSF([1.0, 4.0, 16.0], [0.0], np.array([[-2.0], [-2.3], [-1.0]]), vels=None, min_slope=1.5)
    m2 = load_model(save_model(m, tmp_path / "t.json"))
    assert m2.freqs == (1.0, 4.0, 16.0) and isinstance(m2.freqs, tuple)
    assert m2.vels is None and m2.min_slope == 1.5
    np.testing.assert_array_equal(m2.threshold_frequency(jnp.array([0.01, 0.05])),
                                  m.threshold_frequency(jnp.array([0.01, 0.05])))
    ecc = pmetric.Eccentric(pmetric.KellySpatioTemporal(), pmetric.RovamoVirsu())
    doc = json.loads(save_model(ecc, tmp_path / "e.json").read_text())
    assert doc["format"] == "pmetric-model" and doc["model"]["class"] == "Eccentric"
    assert doc["model"]["fields"]["csf"]["kind"] == "module"
    assert doc["model"]["fields"]["csf"]["class"] == "KellySpatioTemporal"
    e2 = load_model(tmp_path / "e.json")
    np.testing.assert_array_equal(e2.threshold_contrast(F, E, V), ecc.threshold_contrast(F, E, V))


def test_float64_values_exact(tmp_path, x64):
    m = pmetric.ManosSakrison(peak_sensitivity=123.456789012345678)
    assert m.peak_sensitivity.dtype == jnp.float64
    m2 = load_model(save_model(m, tmp_path / "m.json"))
    assert m2.peak_sensitivity.dtype == jnp.float64
    assert float(m2.peak_sensitivity) == float(m.peak_sensitivity)


def _write(tmp_path, obj, name="bad.json"):
    p = tmp_path / name
    p.write_text(obj if isinstance(obj, str) else json.dumps(obj))
    return p


def test_errors(tmp_path):
    good = json.loads(save_model(pmetric.ManosSakrison(), tmp_path / "g.json").read_text())
    with pytest.raises(ValueError, match="does not exist"):
        load_model(tmp_path / "none.json")
    with pytest.raises(ValueError, match=r"not valid JSON \(line 1"):
        load_model(_write(tmp_path, "{not json"))
    with pytest.raises(ValueError, match="not a pmetric model file"):
        load_model(_write(tmp_path, {"hello": 1}))
    with pytest.raises(ValueError, match="unsupported version"):
        load_model(_write(tmp_path, {**good, "version": 99}))
    bad = json.loads(json.dumps(good))
    bad["model"]["class"] = "NoSuchModel"
    with pytest.raises(ValueError, match="unknown model class 'NoSuchModel'"):
        load_model(_write(tmp_path, bad))
    bad = json.loads(json.dumps(good))
    del bad["model"]["fields"]["peak_sensitivity"]
    with pytest.raises(ValueError, match=r"missing field\(s\) \['peak_sensitivity'\]"):
        load_model(_write(tmp_path, bad))
    bad = json.loads(json.dumps(good))
    bad["model"]["fields"]["zzz"] = {"kind": "static", "value": 1}
    with pytest.raises(ValueError, match=r"unknown field\(s\) \['zzz'\]"):
        load_model(_write(tmp_path, bad))
    bad = json.loads(json.dumps(good))
    bad["model"]["fields"]["peak_sensitivity"]["shape"] = [3]
    with pytest.raises(ValueError, match="peak_sensitivity: data has shape"):
        load_model(_write(tmp_path, bad))
    bad = json.loads(json.dumps(good))
    bad["model"]["fields"]["peak_sensitivity"]["data"] = "abc"
    with pytest.raises(ValueError, match="malformed array"):
        load_model(_write(tmp_path, bad))
    bad = json.loads(json.dumps(good))
    bad["model"]["fields"]["printed_constant"] = {"kind": "array", "dtype": "float32", "shape": [], "data": 1.0}
    with pytest.raises(ValueError, match="is static in ManosSakrison but stored as 'array'"):
        load_model(_write(tmp_path, bad))
    with pytest.raises(ValueError, match="expected a pmetric model"):
        save_model("not a model", tmp_path / "x.json")

    class Foreign(CSFModel):
        def sensitivity(self, f, e=0.0, v=0.0):
            return f

    with pytest.raises(ValueError, match="not a registered pmetric model"):
        save_model(Foreign(), tmp_path / "x.json")
    assert not (tmp_path / "x.json").exists()


def test_register_model(tmp_path):
    class Scaled(CSFModel):
        gain: jax.Array

        def sensitivity(self, f, e=0.0, v=0.0):
            return self.gain * jnp.ones_like(jnp.asarray(f))

    pmetric.register_model(Scaled)
    try:
        m2 = load_model(save_model(Scaled(jnp.asarray(3.0)), tmp_path / "s.json"))
        assert float(m2.sensitivity(2.0)) == 3.0
    finally:
        pmetric._registry._EXTRA.pop("Scaled", None)
    assert "Scaled" not in pmetric.model_registry()
    with pytest.raises(ValueError, match="not an equinox.Module"):
        pmetric.register_model(int)


@pytest.mark.parametrize("value, msg", [
    (float("nan"), "must be >= 1e-06, got nan"),
    (-3.0, "must be >= 1e-06, got -3.0"),
    (0.0, "must be >= 1e-06, got 0.0"),
    (1e40, "must fit in float32, got 1e[+]40"),
    (float("inf"), "must be >= 1e-06, got inf"),
])
def test_load_rejects_bad_constants(tmp_path, value, msg):
    """A constant that is NaN, infinite, outside param_bounds or outside its dtype fails to load, naming
    the file and the field (a KellyAbstract with such a delta would make every fold imperceptible)."""
    doc = json.loads(save_model(pmetric.KellyAbstract(), tmp_path / "good.json").read_text())
    doc["model"]["fields"]["delta"]["data"] = value
    p = tmp_path / "m.json"
    p.write_text(json.dumps(doc))  # json writes NaN / Infinity literals, as a hand-edited file might
    with pytest.raises(pmetric.PlodError, match=f"m.json: KellyAbstract.delta {msg}"):
        load_model(p)


def test_load_checks_nested_and_unbounded_constants(tmp_path):
    doc = json.loads(save_model(pmetric.Eccentric(pmetric.ManosSakrison()), tmp_path / "e.json").read_text())
    doc["model"]["fields"]["magnification"]["fields"]["k1"]["data"] = -1.0
    with pytest.raises(pmetric.PlodError, match=r"bad.json: RovamoVirsu.k1 must be >= 0, got -1.0"):
        load_model(_write(tmp_path, doc))
    m = CalibratedCSF([1.0, 4.0], [0.0], np.array([[-2.0], [-1.0]]))
    doc = json.loads(save_model(m, tmp_path / "t.json").read_text())
    doc["model"]["fields"]["log_thresholds"]["data"][1][0] = float("nan")
    with pytest.raises(pmetric.PlodError, match="CalibratedCSF.log_thresholds must be finite, got nan"):
        load_model(_write(tmp_path, doc))


def test_save_refuses_non_finite_constants(tmp_path):
    bad = pmetric.KellyAbstract()
    object.__setattr__(bad, "delta", jnp.asarray(np.nan, jnp.float32))  # what a diverged fit could hold
    with pytest.raises(pmetric.PlodError, match="save_model: KellyAbstract.delta must be finite, got nan"):
        save_model(bad, tmp_path / "bad.json")
    assert not (tmp_path / "bad.json").exists()
    good = save_model(pmetric.KellyAbstract(), tmp_path / "good.json").read_text()
    assert "NaN" not in good and "Infinity" not in good


def test_save_refuses_what_load_would_refuse(tmp_path):
    """A constant the constructor accepts but the file's bounds refuse (KellyAbstract delta 1e-7 < 1e-6) is
    refused at save time, naming it: save never writes a file load_model cannot read."""
    m = pmetric.KellyAbstract(delta=1e-7)
    with pytest.raises(pmetric.PlodError, match=r"save_model: KellyAbstract.delta must be >= 1e-06, got 1(\.0+\d*)?e-07"):
        save_model(m, tmp_path / "m.json")
    assert not (tmp_path / "m.json").exists()
    ok = save_model(pmetric.KellyAbstract(delta=2e-6), tmp_path / "ok.json")
    assert float(load_model(ok).delta) == pytest.approx(2e-6, rel=1e-6)
