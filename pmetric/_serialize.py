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

Classes are looked up by name in a registry of pmetric's models: every subclass of ``CSFModel``
defined in pmetric, every ``equinox.Module`` exported by ``pmetric`` (``RovamoVirsu``, ``Display``) and
classes added with :func:`register_model`. Loading restores the fields directly (no ``__init__``) and then
runs the classes' ``__check_init__`` validators. float64 arrays load as float32 when ``jax_enable_x64`` is
off. Files are written atomically.
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

__all__ = ["save_model", "load_model", "model_to_dict", "model_from_dict", "register_model", "model_registry"]

FORMAT = "pmetric-model"
VERSION = 1

_EXTRA: dict[str, type] = {}


def register_model(cls: type) -> type:
    """Make a (non-pmetric) ``equinox.Module`` class loadable by name; usable as a decorator."""
    if not (isinstance(cls, type) and issubclass(cls, eqx.Module)):
        raise ValueError(f"register_model: {cls!r} is not an equinox.Module class")
    _EXTRA[cls.__name__] = cls
    return cls


def model_registry() -> dict[str, type]:
    """Name -> class of every model class ``load_model`` can rebuild (built at call time)."""
    import pmetric  # late import: the package imports this module
    from ._base import CSFModel

    reg: dict[str, type] = {}
    stack = [CSFModel]
    while stack:
        k = stack.pop()
        for sub in k.__subclasses__():
            stack.append(sub)
            if sub.__module__.split(".")[0] == "pmetric" and not getattr(sub, "__abstractmethods__", None):
                reg[sub.__name__] = sub
    for name, obj in vars(pmetric).items():
        if isinstance(obj, type) and issubclass(obj, eqx.Module) and not getattr(obj, "__abstractmethods__", None):
            reg.setdefault(obj.__name__, obj)
    reg.update(_EXTRA)
    return reg


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
    raise ValueError(f"save_model: {where} holds a {type(v).__name__}, which cannot be stored as JSON")


def _decode_static(v: Any):
    if isinstance(v, dict):
        if set(v) != {"tuple"} or not isinstance(v["tuple"], list):
            raise ValueError(f"malformed static value {v!r}")
        return tuple(_decode_static(x) for x in v["tuple"])
    if isinstance(v, list):
        return [_decode_static(x) for x in v]
    return v


def model_to_dict(model: eqx.Module) -> dict:
    """The JSON-ready description of ``model`` (see the module docstring)."""
    if not isinstance(model, eqx.Module):
        raise ValueError(f"save_model: expected a pmetric model (equinox.Module), got {type(model).__name__}")
    name = type(model).__name__
    reg = model_registry()
    if reg.get(name) is not type(model):
        raise ValueError(f"save_model: class {name!r} is not a registered pmetric model; "
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
            if isinstance(val, jax.core.Tracer):
                raise ValueError(f"save_model: {where} is a traced value; save outside jit")
            a = np.asarray(val)
            if a.dtype.kind not in "fiub":
                raise ValueError(f"save_model: {where} has unsupported dtype {a.dtype}")
            fields[fld.name] = {"kind": "array", "dtype": str(a.dtype), "shape": list(a.shape), "data": a.tolist()}
        else:
            fields[fld.name] = {"kind": "static", "value": _encode_static(val, where)}
    return {"class": name, "fields": fields}


def model_from_dict(d: Any, *, _where: str = "model") -> eqx.Module:
    """Rebuild a model from :func:`model_to_dict` output; ValueError naming the problem."""
    if not isinstance(d, dict) or "class" not in d or "fields" not in d or not isinstance(d["fields"], dict):
        raise ValueError(f"load_model: {_where} must be an object with 'class' and 'fields'")
    name = d["class"]
    reg = model_registry()
    if name not in reg:
        raise ValueError(f"load_model: unknown model class {name!r} at {_where}; known: {sorted(reg)}")
    cls = reg[name]
    stored = d["fields"]
    flds = {f.name: f for f in dataclasses.fields(cls)}
    missing = [n for n in flds if n not in stored]
    extra = [n for n in stored if n not in flds]
    if missing:
        raise ValueError(f"load_model: {name} at {_where} is missing field(s) {missing}")
    if extra:
        raise ValueError(f"load_model: {name} at {_where} has unknown field(s) {extra}")
    values = {}
    for n, fld in flds.items():
        enc = stored[n]
        where = f"{_where}.{n}"
        if not isinstance(enc, dict) or enc.get("kind") not in ("array", "module", "static"):
            raise ValueError(f"load_model: field {where} must be an object with kind 'array', 'module' or 'static'")
        kind = enc["kind"]
        is_static = fld.metadata.get("static", False)
        if is_static and kind != "static":
            raise ValueError(f"load_model: field {where} is static in {name} but stored as {kind!r}")
        if kind == "static":
            try:
                values[n] = _decode_static(enc.get("value"))
            except ValueError as exc:
                raise ValueError(f"load_model: field {where}: {exc}") from None
        elif kind == "module":
            values[n] = model_from_dict(enc, _where=where)
        else:
            try:
                dtype = np.dtype(enc["dtype"])
                a = np.asarray(enc["data"], dtype=dtype)
                shape = tuple(enc["shape"])
            except (KeyError, TypeError, ValueError) as exc:
                raise ValueError(f"load_model: field {where}: malformed array ({exc})") from None
            if dtype.kind not in "fiub":
                raise ValueError(f"load_model: field {where}: unsupported dtype {dtype}")
            if a.size == 0 and 0 in shape:
                a = a.reshape(shape)  # nested lists cannot carry the shape of an empty array
            if a.shape != shape:
                raise ValueError(f"load_model: field {where}: data has shape {a.shape}, header says {shape}")
            values[n] = jnp.asarray(a)
    obj = object.__new__(cls)
    for n, v in values.items():
        object.__setattr__(obj, n, v)
    for k in reversed(cls.__mro__):
        chk = k.__dict__.get("__check_init__")
        if chk is not None:
            chk(obj)
    return obj


def save_model(model: eqx.Module, path: str | os.PathLike) -> Path:
    """Write ``model`` to ``path`` as JSON, atomically; returns the path."""
    doc = {"format": FORMAT, "version": VERSION, "model": model_to_dict(model)}
    return atomic_write_text(path, json.dumps(doc, indent=1) + "\n")


def load_model(path: str | os.PathLike) -> eqx.Module:
    """Read a model written by :func:`save_model`. ValueError for a missing file, malformed JSON, an
    unknown class, missing or unknown fields."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ValueError(f"load_model: {str(p)!r} does not exist") from None
    except UnicodeDecodeError:
        raise ValueError(f"load_model: {str(p)!r} is not UTF-8 text") from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"load_model: {str(p)!r} is not valid JSON (line {exc.lineno}, column {exc.colno}: "
                         f"{exc.msg})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError(f"load_model: {str(p)!r} is not a pmetric model file (no \"format\": \"{FORMAT}\")")
    if doc.get("version") != VERSION:
        raise ValueError(f"load_model: {str(p)!r} has unsupported version {doc.get('version')!r} (expected {VERSION})")
    if "model" not in doc:
        raise ValueError(f"load_model: {str(p)!r} has no 'model' entry")
    return model_from_dict(doc["model"])
