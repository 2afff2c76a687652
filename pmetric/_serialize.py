"""Save and load pmetric models as JSON (class name + field values).

File layout (UTF-8 JSON)::

    {"format": "pmetric-model", "version": 1,
     "model": {"class": "Eccentric",
               "fields": {"csf": {"kind": "module", "class": "ManosSakrison", "fields": {...}},
                          "magnification": {"kind": "module", ...}}}}

Each field is one of

* ``{"kind": "array", "dtype": "float32", "shape": [..], "data": nested lists}`` -- a JAX array field;
* ``{"kind": "module", "class": ..., "fields": {...}}`` -- a nested pmetric model (e.g. the ``csf`` and
  ``magnification`` of ``Eccentric``);
* ``{"kind": "static", "value": ...}`` -- a static field (switch) or a ``None``; tuples are written as
  ``{"tuple": [...]}`` so they come back as tuples (static fields must stay hashable).

Classes are looked up by name in pmetric's one model table (:func:`pmetric.model_registry`, see
``pmetric/_registry.py``). Loading restores the fields directly (no ``__init__``), checks every floating
constant (finite, representable in its dtype, inside the class's ``param_bounds``) and then runs the
classes' ``__check_init__`` validators; ``save_model`` refuses non-finite constants, so a file it writes
holds no ``NaN``. float64 arrays load as float32 when ``jax_enable_x64`` is off. Files are written
atomically. Every problem raises :class:`pmetric.PlodError` naming the file and the field, e.g.
``m.json: KellyAbstract.delta must be >= 1e-06, got nan``.
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._atomic import atomic_write_text
from ._errors import PlodError
from ._registry import _EXTRA, model_registry, register_model  # noqa: F401  (one table: pmetric._registry)

__all__ = ["save_model", "load_model", "model_to_dict", "model_from_dict", "register_model", "model_registry"]

FORMAT = "pmetric-model"
VERSION = 1


# ---------------------------------------------------------------------------- encoding
def _encode_static(v: Any, where: str):
    if isinstance(v, tuple):
        return {"tuple": [_encode_static(x, where) for x in v]}
    if isinstance(v, list):
        return [_encode_static(x, where) for x in v]
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    if isinstance(v, (np.integer, np.floating, np.bool_)):
        return v.item()
    raise PlodError(f"save_model: {where} holds a {type(v).__name__}, which cannot be stored as JSON")


def _decode_static(v: Any):
    if isinstance(v, dict):
        if set(v) != {"tuple"} or not isinstance(v["tuple"], list):
            raise PlodError(f"malformed static value {v!r}")
        return tuple(_decode_static(x) for x in v["tuple"])
    if isinstance(v, list):
        return [_decode_static(x) for x in v]
    return v


def _encode_array(val, where: str) -> dict:
    if isinstance(val, jax.core.Tracer):
        raise PlodError(f"save_model: {where} is a traced value; save outside jit")
    a = np.asarray(val)
    if a.dtype.kind not in "fiub":
        raise PlodError(f"save_model: {where} has unsupported dtype {a.dtype}")
    if a.dtype.kind == "f" and not np.isfinite(a).all():
        raise PlodError(f"save_model: {where} must be finite, got {_first_bad(a, np.isfinite(a))}; "
                        "refusing to write a model that would load as broken")
    return {"kind": "array", "dtype": str(a.dtype), "shape": list(a.shape), "data": a.tolist()}


def model_to_dict(model: eqx.Module) -> dict:
    """The JSON-ready description of ``model`` (see the module docstring)."""
    if not isinstance(model, eqx.Module):
        raise PlodError(f"save_model: expected a pmetric model (equinox.Module), got {type(model).__name__}")
    name = type(model).__name__
    if model_registry().get(name) is not type(model):
        raise PlodError(f"save_model: class {name!r} is not a registered pmetric model; "
                        "register it with pmetric.register_model")
    fields = {}
    for fld in dataclasses.fields(model):
        val = getattr(model, fld.name)
        where = f"{name}.{fld.name}"
        if fld.metadata.get("static", False):
            fields[fld.name] = {"kind": "static", "value": _encode_static(val, where)}
        elif isinstance(val, eqx.Module):
            fields[fld.name] = {"kind": "module", **model_to_dict(val)}
        elif isinstance(val, (jax.Array, np.ndarray, np.generic)):
            fields[fld.name] = _encode_array(val, where)
        else:
            fields[fld.name] = {"kind": "static", "value": _encode_static(val, where)}
    return {"class": name, "fields": fields}


# ---------------------------------------------------------------------------- decoding
def _first_bad(a: np.ndarray, ok: np.ndarray):
    """The first value of ``a`` where ``ok`` is False, as a Python number."""
    return np.asarray(a).ravel()[np.flatnonzero(~np.asarray(ok).ravel())[0]].item()


def _check_constant(raw: np.ndarray, dtype: np.dtype, cls: type, name: str, src: str) -> None:
    """Finite, representable as ``dtype`` and inside ``cls.param_bounds[name]``; PlodError otherwise."""
    where = f"{src}: {cls.__name__}.{name}"
    lo, hi = (getattr(cls, "param_bounds", None) or {}).get(name, (None, None))
    ok = np.isfinite(raw)
    if lo is not None:
        ok &= raw >= lo
    if hi is not None:
        ok &= raw <= hi
    if not ok.all():
        rule = ("must be finite" if lo is None and hi is None else
                f"must be >= {lo:g}" if hi is None else
                f"must be <= {hi:g}" if lo is None else f"must be in [{lo:g}, {hi:g}]")
        raise PlodError(f"{where} {rule}, got {_first_bad(raw, ok)}")
    dtype = np.dtype(jax.dtypes.canonicalize_dtype(dtype))  # float64 loads as float32 without x64
    with np.errstate(over="ignore"):
        cast = raw.astype(dtype)
    if not np.isfinite(cast).all():
        raise PlodError(f"{where} must fit in {dtype}, got {_first_bad(raw, np.isfinite(cast))}")


def _decode_array(enc: dict, where: str) -> np.ndarray:
    try:
        dtype = np.dtype(enc["dtype"])
        a = np.asarray(enc["data"], dtype=np.float64 if dtype.kind == "f" else dtype)
        shape = tuple(enc["shape"])
    except (KeyError, TypeError, ValueError) as exc:
        raise PlodError(f"field {where}: malformed array ({exc})") from None
    if dtype.kind not in "fiub":
        raise PlodError(f"field {where}: unsupported dtype {dtype}")
    if a.size == 0 and 0 in shape:
        a = a.reshape(shape)  # nested lists cannot carry the shape of an empty array
    if a.shape != shape:
        raise PlodError(f"field {where}: data has shape {a.shape}, header says {shape}")
    return a


def _decode_field(enc: Any, fld, cls: type, where: str, src: str):
    if not isinstance(enc, dict) or enc.get("kind") not in ("array", "module", "static"):
        raise PlodError(f"field {where} must be an object with kind 'array', 'module' or 'static'")
    kind = enc["kind"]
    if fld.metadata.get("static", False) and kind != "static":
        raise PlodError(f"field {where} is static in {cls.__name__} but stored as {kind!r}")
    if kind == "static":
        try:
            return _decode_static(enc.get("value"))
        except PlodError as exc:
            raise PlodError(f"field {where}: {exc}") from None
    if kind == "module":
        return _from_dict(enc, where, src)
    a = _decode_array(enc, where)
    dtype = np.dtype(enc["dtype"])
    if dtype.kind == "f":
        _check_constant(a, dtype, cls, fld.name, src)
        a = a.astype(dtype)
    return jnp.asarray(a)


def _from_dict(d: Any, where: str, src: str) -> eqx.Module:
    if not isinstance(d, dict) or "class" not in d or "fields" not in d or not isinstance(d["fields"], dict):
        raise PlodError(f"{where} must be an object with 'class' and 'fields'")
    name = d["class"]
    reg = model_registry()
    if name not in reg:
        raise PlodError(f"unknown model class {name!r} at {where}; known: {sorted(reg)}")
    cls = reg[name]
    stored = d["fields"]
    flds = {f.name: f for f in dataclasses.fields(cls)}
    missing = [n for n in flds if n not in stored]
    extra = [n for n in stored if n not in flds]
    if missing:
        raise PlodError(f"{name} at {where} is missing field(s) {missing}")
    if extra:
        raise PlodError(f"{name} at {where} has unknown field(s) {extra}")
    obj = object.__new__(cls)
    for n, fld in flds.items():
        object.__setattr__(obj, n, _decode_field(stored[n], fld, cls, f"{where}.{n}", src))
    for k in reversed(cls.__mro__):
        chk = k.__dict__.get("__check_init__")
        if chk is not None:
            try:
                chk(obj)
            except PlodError:
                raise
            except ValueError as exc:
                raise PlodError(f"{src}: {name} at {where}: {exc}") from None
    return obj


def model_from_dict(d: Any, *, _where: str = "model", _source: str = "load_model") -> eqx.Module:
    """Rebuild a model from :func:`model_to_dict` output; PlodError naming the problem."""
    try:
        return _from_dict(d, _where, _source)
    except PlodError as exc:
        msg = str(exc)
        raise PlodError(msg if msg.startswith(f"{_source}: ") else f"{_source}: {msg}") from None


def save_model(model: eqx.Module, path: str | os.PathLike) -> Path:
    """Write ``model`` to ``path`` as JSON, atomically; returns the path. PlodError (nothing written) for
    a non-finite constant, an unregistered class, a value JSON cannot hold, or anything :func:`load_model`
    would refuse (a constant outside the class's ``param_bounds``: the file is checked as it will be read)."""
    doc = {"format": FORMAT, "version": VERSION, "model": model_to_dict(model)}
    model_from_dict(doc["model"], _source="save_model")  # never write a file that cannot be loaded
    try:
        text = json.dumps(doc, indent=1, allow_nan=False)
    except ValueError as exc:  # a NaN or infinite static value
        raise PlodError(f"save_model: {type(model).__name__} holds a value JSON cannot store ({exc})") from None
    if Path(path).is_dir():  # before: IsADirectoryError from the atomic rename
        raise PlodError(f"save_model: {str(path)!r} is a directory; give a file name")
    return atomic_write_text(path, text + "\n")


def load_model(path: str | os.PathLike) -> eqx.Module:
    """Read a model written by :func:`save_model`. PlodError naming the file for a missing file, malformed
    JSON, an unknown class, missing or unknown fields, or a constant that is not finite or outside the
    class's ``param_bounds``."""
    p = Path(path)
    src = str(p)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise PlodError(f"load_model: {src!r} does not exist") from None
    except IsADirectoryError:
        raise PlodError(f"load_model: {src!r} is a directory, not a model file") from None
    except UnicodeDecodeError:
        raise PlodError(f"load_model: {src!r} is not UTF-8 text") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise PlodError(f"load_model: {src!r} is not valid JSON (line {exc.lineno}, column {exc.colno}: "
                        f"{exc.msg})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise PlodError(f"load_model: {src!r} is not a pmetric model file (no \"format\": \"{FORMAT}\")")
    if doc.get("version") != VERSION:
        raise PlodError(f"load_model: {src!r} has unsupported version {doc.get('version')!r} "
                        f"(expected {VERSION})")
    if "model" not in doc:
        raise PlodError(f"load_model: {src!r} has no 'model' entry")
    return model_from_dict(doc["model"], _source=src)
