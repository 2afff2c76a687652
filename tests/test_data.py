"""Tests for optim.fit.CalibrationData (CSV reading, validation, selection, atomic output)."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import optim.fit
from optim.fit import CalibrationData

_FLOATS = ("f", "t_frequency", "velocity", "e", "luminance", "area", "log_threshold", "n",
           "var_log_threshold", "vis_field", "ge_sigma", "orientation")
_STRS = ("dataset", "observer", "stimulus", "source")


def _same(a: CalibrationData, b: CalibrationData):
    assert len(a) == len(b)
    for k in _FLOATS:
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    for k in _STRS:
        assert getattr(a, k).tolist() == getattr(b, k).tolist(), k


def _write(tmp_path, text, name="d.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


GOOD = """dataset,luminance,s_frequency,t_frequency,eccentricity,area,N,log_cone_contrast
a,100,2,4,0,1,3,-2
a,100,4,0,10,,1,-1.5
b,,8,8,5,2,,-1
"""


def test_small_csv_values(tmp_path):
    d = CalibrationData.from_csv(_write(tmp_path, GOOD))
    assert len(d) == 3
    np.testing.assert_array_equal(d.f, [2, 4, 8])
    np.testing.assert_array_equal(d.t_frequency, [4, 0, 8])
    np.testing.assert_array_equal(d.velocity, [2.0, 0.0, 1.0])  # t_frequency / s_frequency (deg/s)
    np.testing.assert_array_equal(d.e, [0, 10, 5])
    assert np.isnan(d.luminance[2]) and d.luminance[0] == 100
    assert np.isnan(d.area[1])
    np.testing.assert_array_equal(d.n, [3, 1, 1])  # empty N -> 1
    np.testing.assert_allclose(d.threshold, [0.01, 10 ** -1.5, 0.1])
    np.testing.assert_allclose(d.sensitivity, [100, 10 ** 1.5, 10])
    assert d.datasets == ["a", "b"]
    parts = d.by_dataset()
    assert list(parts) == ["a", "b"] and len(parts["a"]) == 2 and len(parts["b"]) == 1
    np.testing.assert_array_equal(parts["b"].f, [8])
    assert d.observer.tolist() == ["", "", ""]
    assert "3 rows" in d.summary() and "cycles/deg" in d.summary()


def test_velocity_column_and_sensitivity(tmp_path):
    text = "s_frequency,velocity,sensitivity\n2,3,50\n0.5,0,200\n"
    d = CalibrationData.from_csv(_write(tmp_path, text, "user.csv"))
    np.testing.assert_array_equal(d.velocity, [3, 0])
    np.testing.assert_array_equal(d.t_frequency, [6, 0])  # Hz = deg/s * cycles/deg
    np.testing.assert_allclose(d.log_threshold, [-np.log10(50), -np.log10(200)])
    np.testing.assert_array_equal(d.e, [0, 0])  # absent eccentricity -> 0
    assert d.dataset.tolist() == ["user", "user"]  # file stem


def test_unit_suffix_headers(tmp_path):
    text = "s_frequency_cpd,t_frequency_hz,luminance_cdm2,area_deg2,eccentricity_deg,sensitivity\n4,2,100,1,3,10\n"
    d = CalibrationData.from_csv(_write(tmp_path, text))
    assert d.f[0] == 4 and d.velocity[0] == 0.5 and d.luminance[0] == 100 and d.e[0] == 3
    with pytest.raises(ValueError, match=r"line 1.*s_frequency_cpm.*unknown unit 'cpm'"):
        CalibrationData.from_csv(_write(tmp_path, "s_frequency_cpm,sensitivity\n4,10\n"))


@pytest.mark.parametrize(
    "text, pattern",
    [
        ("", r"empty file"),
        ("s_frequency,log_cone_contrast\n", r"no data rows"),
        ("log_cone_contrast\n-2\n", r"line 1.*missing required column 's_frequency'"),
        ("s_frequency,eccentricity\n1,0\n", r"line 1.*missing required column 'log_cone_contrast'"),
        ("s_frequency,log_cone_contrast\n1,-2\n2,abc\n", r"line 3, column 'log_cone_contrast'.*'abc' is not a number"),
        ("s_frequency,log_cone_contrast\n1,-2\n\n2,NaN\n", r"line 4, column 'log_cone_contrast'.*NaN"),
        ("s_frequency,log_cone_contrast\n-1,-2\n", r"line 2, column 's_frequency'.*negative"),
        ("s_frequency,eccentricity,log_cone_contrast\n1,-3,-2\n", r"line 2, column 'eccentricity'.*negative.*\(got -3\.0\)$"),
        ("s_frequency,sensitivity\n1,10\n1,0\n", r"line 3, column 'sensitivity'.*> 0"),
        ("s_frequency,sensitivity\n1,-5\n", r"line 2, column 'sensitivity'.*> 0"),
        ("s_frequency,luminance,sensitivity\n1,-5,3\n", r"line 2, column 'luminance'"),
        ("s_frequency,log_cone_contrast\n1,-2,7\n", r"line 2: 3 cells"),
        ("s_frequency,t_frequency,log_cone_contrast\n0,4,-1\n", r"line 2, column 't_frequency'.*s_frequency 0"),
        ("s_frequency,log_cone_contrast,sensitivity\n1,-2,50\n", r"line 2, column 'sensitivity'.*disagrees"),
        ("s_frequency,t_frequency,velocity,log_cone_contrast\n2,4,3,-1\n", r"line 2, column 'velocity'.*disagrees"),
        ("s_frequency,S_FREQUENCY_cpd,log_cone_contrast\n2,4,-1\n", r"appears twice"),
    ],
)
def test_bad_csv(tmp_path, text, pattern):
    with pytest.raises(ValueError, match=pattern):
        CalibrationData.from_csv(_write(tmp_path, text))


def test_missing_file(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        CalibrationData.from_csv(tmp_path / "nope.csv")


def test_from_arrays_and_errors():
    d = CalibrationData.from_arrays([1, 2, 4], [-2, -2.5, -2.2], e=[0, 0, 10], velocity=1.0, observer="me")
    np.testing.assert_array_equal(d.t_frequency, [1, 2, 4])
    assert d.observer.tolist() == ["me"] * 3 and d.dataset.tolist() == ["data"] * 3
    d2 = CalibrationData.from_arrays([1, 2], sensitivity=[100, 10])
    np.testing.assert_allclose(d2.log_threshold, [-2, -1])
    with pytest.raises(ValueError, match="exactly one"):
        CalibrationData.from_arrays([1], [-1], sensitivity=[10])
    with pytest.raises(ValueError, match="at most one"):
        CalibrationData.from_arrays([1], [-1], t_frequency=1, velocity=1)
    with pytest.raises(ValueError, match="do not broadcast"):
        CalibrationData.from_arrays([1, 2], [-1, -2, -3])
    with pytest.raises(ValueError, match=r"row 1, column 'f'.*NaN"):
        CalibrationData.from_arrays([1, np.nan], [-1, -2])
    with pytest.raises(ValueError, match=r"row 0, column 'e'.*negative"):
        CalibrationData.from_arrays([1, 2], [-1, -2], e=[-1, 0])


def test_subset_and_immutability():
    d = CalibrationData.from_arrays([1, 2, 4, 8], [-2, -2.5, -2.2, -1.5])
    s = d.subset(d.f > 1.5)
    np.testing.assert_array_equal(s.f, [2, 4, 8])
    np.testing.assert_array_equal(d.subset(np.array([3, 0])).log_threshold, [-1.5, -2])
    with pytest.raises(ValueError, match="boolean mask has shape"):
        d.subset(np.array([True, False]))
    with pytest.raises(ValueError, match="out of range"):
        d.subset(np.array([7]))
    with pytest.raises(AttributeError):
        d.f = np.zeros(4)
    with pytest.raises(ValueError):
        d.f[0] = 3.0  # read-only arrays
    both = CalibrationData.concatenate([d, s])
    assert len(both) == 7


def test_to_csv_round_trip(tmp_path):
    d = CalibrationData.from_csv(_write(tmp_path, GOOD))
    out = d.to_csv(tmp_path / "out" / "copy.csv")
    _same(d, CalibrationData.from_csv(out))
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["copy.csv"]  # no temp files left


@pytest.mark.shared
def test_real_achromatic_file(shared_dir, tmp_path):
    path = shared_dir / "data" / "csf" / "achromatic_thresholds.csv"
    d = CalibrationData.from_csv(path)
    assert len(d) == 787
    assert len(d.datasets) == 12 and "robson1966" in d.datasets
    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    # independent reading with the csv module agrees row by row
    np.testing.assert_array_equal(d.f, [float(r["s_frequency"]) for r in rows])
    np.testing.assert_array_equal(d.log_threshold, [float(r["log_cone_contrast"]) for r in rows])
    np.testing.assert_allclose(d.sensitivity, [float(r["sensitivity"]) for r in rows], rtol=1e-4)
    tf = np.array([float(r["t_frequency"]) for r in rows])
    f = np.array([float(r["s_frequency"]) for r in rows])
    moving = tf > 0
    np.testing.assert_allclose(d.velocity[moving], tf[moving] / f[moving])
    assert np.all(d.velocity[~moving] == 0)
    assert sum(len(p) for p in d.by_dataset().values()) == 787
    assert len(d.by_dataset()["robson1966"]) == 97
    _same(d, CalibrationData.from_csv(d.to_csv(tmp_path / "copy.csv")))


@pytest.mark.shared
def test_real_modelfest_observers(shared_dir):
    d = CalibrationData.from_csv(shared_dir / "data" / "csf" / "modelfest_individual.csv")
    assert len(d) == 896
    obs = d.by_observer()
    assert len(obs) == 16 and all(len(o) == 56 for o in obs.values())
    assert np.all(d.n == 1)  # the N column is empty there
    assert np.all(d.luminance == 30) and np.all(np.isinf(d.var_log_threshold))
    assert sorted(set(np.round(d.f, 2))) == [1.12, 2, 2.83, 4, 5.66, 8, 11.3, 16, 22.6, 30]


def test_public_export():
    assert optim.fit.CalibrationData is CalibrationData


_finite = dict(allow_nan=False, allow_infinity=False)


@given(
    st.lists(
        st.tuples(
            st.floats(1e-3, 100.0, **_finite),   # f, cycles/deg
            st.floats(-3.0, 0.5, **_finite),    # log10 threshold
            st.floats(0.0, 80.0, **_finite),    # e, deg
            st.floats(0.0, 50.0, **_finite),    # t_frequency, Hz
            st.sampled_from(["a", "b,c", 'q"d', ""]),  # labels needing CSV quoting
        ),
        min_size=1,
        max_size=8,
    )
)
def test_csv_round_trip_property(tmp_path_factory, rows):
    f, y, e, tf, lab = (list(x) for x in zip(*rows))
    d = CalibrationData.from_arrays(f, y, e=e, t_frequency=tf, dataset=lab, observer=lab)
    np.testing.assert_allclose(d.velocity * d.f, d.t_frequency, rtol=1e-12, atol=1e-300)
    path = tmp_path_factory.mktemp("rt") / "d.csv"
    _same(d, CalibrationData.from_csv(d.to_csv(path)))
