"""The one table of pmetric's models: names, aliases, inputs, constants, and :func:`make_model`.

Every place that turns a user's word into a model (``plod`` commands, configs, experiments) and the
serializer (:func:`pmetric.load_model`) read this table. A model is named by

* its class name or an alias, case-insensitive, ignoring ``-``, ``_`` and spaces: ``KellyAbstract``,
  ``kellyabstract``, ``kelly-abstract``, ``stela``, ``stelacsf``, ``barten``, ``manos`` ...;
* a composition ``eccentric(CSF)`` or ``eccentric:CSF``: a foveal CSF scaled by the Rovamo-Virsu cortical
  magnification ``M(e)`` [Red01 Eq 3]; plain ``eccentric`` is ``eccentric(manossakrison)``;
* ``default``: :data:`DEFAULT_MODEL`;
* a path to a fitted model file (``*.json`` or any existing file): :func:`pmetric.load_model`.

Unknown names raise :class:`pmetric.PlodError` listing the valid names, with a close match when there is
one. The table is built at call time from every concrete ``CSFModel`` subclass defined in pmetric, every
``equinox.Module`` class exported by ``pmetric`` (``RovamoVirsu``, ``Display``: loadable components, not
CSF models) and the classes added with :func:`register_model`.
"""

from __future__ import annotations

import dataclasses
import difflib
import os
import re
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import numpy as np

from ._errors import PlodError

__all__ = ["DEFAULT_MODEL", "ModelEntry", "default_model", "make_model", "model_entries", "model_registry",
           "register_model"]

DEFAULT_MODEL = "stela"
"""The model used when none is given: stelaCSF [MAC22] with its published constants. Of plod's models it
has the least error on thresholds no fit saw in the periphery, where gaze-directed LOD relies on it
(``reports/fit_real/report.md``: 6.90 dB on anderson1991, 8-55 deg), and under the image judge its cuts
beat those of Kelly's abstract CSF [LHNW00], the seeds' model and plod's default before
(``reports/accuracy/default_model.md``). The seeds' reproductions name ``kellyabstract`` explicitly."""

# Extra spellings of the class names (compared after :func:`_key`).
_ALIASES: dict[str, tuple[str, ...]] = {
    "ManosSakrison": ("manos",),
    "KellySpatioTemporal": ("kellyst",),
    "StelaCSF": ("stela",),
    "ReddyAcuity": ("reddy", "acuity"),
    "CalibratedCSF": ("calibrated",),
    "RovamoVirsu": ("rovamo",),
}
# Wrappers around a foveal CSF, and the CSF a bare name wraps.
_WRAPPERS: dict[str, str] = {"Eccentric": "ManosSakrison"}

_EXTRA: dict[str, tuple[type, tuple[str, ...]]] = {}
_COMPOSE = re.compile(r"^\s*([A-Za-z][\w\- ]*?)\s*(?:\((.*)\)|:(.*))\s*$")


def _key(name: str) -> str:
    return re.sub(r"[\s_\-]", "", str(name)).lower()


def register_model(cls: type | None = None, *, aliases: tuple[str, ...] = ()):
    """Make a (non-pmetric) ``equinox.Module`` class loadable and buildable by name (and ``aliases``);
    usable as a decorator, bare or as ``@register_model(aliases=(...))``."""
    if cls is None:
        return lambda c: register_model(c, aliases=aliases)
    if not (isinstance(cls, type) and issubclass(cls, eqx.Module)):
        raise PlodError(f"register_model: {cls!r} is not an equinox.Module class")
    _EXTRA[cls.__name__] = (cls, tuple(aliases))
    return cls


def _concrete(cls) -> bool:
    return isinstance(cls, type) and issubclass(cls, eqx.Module) and not getattr(cls, "__abstractmethods__", None)


def model_registry() -> dict[str, type]:
    """Class name -> class of every model class ``load_model`` can rebuild (built at call time)."""
    import pmetric  # late import: the package imports this module

    from ._base import CSFModel

    reg: dict[str, type] = {}
    stack = [CSFModel]
    while stack:
        for sub in stack.pop().__subclasses__():
            stack.append(sub)
            if sub.__module__.split(".")[0] == "pmetric" and _concrete(sub):
                reg[sub.__name__] = sub
    for obj in vars(pmetric).values():
        if _concrete(obj):
            reg.setdefault(obj.__name__, obj)
    reg.update({name: cls for name, (cls, _) in _EXTRA.items()})
    return reg


# ---------------------------------------------------------------------------------------------- entries
@dataclasses.dataclass(frozen=True)
class ModelEntry:
    """One row of the table: a class, its spellings and (built on demand) its default instance."""

    name: str
    cls: type
    aliases: tuple[str, ...]

    @property
    def is_csf(self) -> bool:
        """A CSF model (what :func:`make_model` builds) rather than a loadable component."""
        from ._base import CSFModel

        return issubclass(self.cls, CSFModel)

    @property
    def wraps(self) -> str | None:
        """Class name of the CSF a bare name wraps (``Eccentric``: ``ManosSakrison``), else None."""
        return _WRAPPERS.get(self.name)

    def build(self, inner: eqx.Module | None = None):
        """An instance with default constants (wrapping ``inner``); PlodError when it needs arguments."""
        try:
            if self.wraps is not None:
                return self.cls(inner if inner is not None else make_model(self.wraps))
            if inner is not None:
                raise PlodError(f"model {self.name} wraps no other model; only "
                                f"{', '.join(f'{w.lower()}(CSF)' for w in _WRAPPERS)} takes one")
            return self.cls()
        except TypeError as exc:
            raise PlodError(f"model {self.name} cannot be built from its name ({exc}); "
                            "give a fitted model .json instead") from None
        except PlodError:
            raise
        except ValueError as exc:
            raise PlodError(f"model {self.name}: {exc}") from None

    def default(self):
        """The instance built from the bare name, or None when the class needs arguments."""
        try:
            return self.build()
        except PlodError:
            return None

    def inputs(self) -> tuple[str, ...] | None:
        """The declared inputs (``"f", "e", "v", "luminance", "area"``); None for components."""
        declared = getattr(self.cls, "inputs", None)
        if isinstance(declared, tuple):
            return declared
        inst = self.default()
        value = getattr(inst, "inputs", None) if inst is not None else None
        return tuple(value) if isinstance(value, (tuple, list)) else None

    def constants(self) -> dict[str, Any] | None:
        """Floating array fields of the default instance (nested ones dotted: ``csf.peak_sensitivity``) ->
        value (float or nested list); None when the class cannot be built from its name."""
        inst = self.default()
        return None if inst is None else _float_fields(inst)


def _float_fields(module, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for fld in dataclasses.fields(module):
        val = getattr(module, fld.name)
        if isinstance(val, eqx.Module):
            out.update(_float_fields(val, f"{prefix}{fld.name}."))
        elif isinstance(val, (jax.Array, np.ndarray)) and np.asarray(val).dtype.kind == "f":
            out[prefix + fld.name] = np.asarray(val).tolist()
    return out


def model_entries() -> dict[str, ModelEntry]:
    """Class name -> :class:`ModelEntry` of every registered class (CSF models first, then by name)."""
    reg = model_registry()
    entries = {}
    for name, cls in reg.items():
        aliases = _ALIASES.get(name, ()) + (_EXTRA[name][1] if name in _EXTRA else ())
        entries[name] = ModelEntry(name, cls, tuple(dict.fromkeys(aliases)))
    return dict(sorted(entries.items(), key=lambda kv: (not kv[1].is_csf, kv[0].lower())))


def _lookup() -> dict[str, ModelEntry]:
    """Normalized spelling -> entry; class names win over aliases."""
    entries = model_entries().values()
    table = {_key(e.name): e for e in entries}
    for entry in entries:
        for alias in entry.aliases:
            table.setdefault(_key(alias), entry)
    return table


def _valid_names(entries) -> str:
    names = [f"{e.name}(CSF)" if e.wraps else e.name for e in entries if e.is_csf]
    return ", ".join(names)


# ---------------------------------------------------------------------------------------------- make_model
def _from_file(spec):
    from ._base import CSFModel
    from ._serialize import load_model

    p = Path(spec)
    if not p.is_file():
        raise PlodError(f"model file not found: {str(p)!r}")
    model = load_model(p)
    if not isinstance(model, CSFModel):
        raise PlodError(f"{p}: holds a {type(model).__name__}, not a CSF model")
    return model


def _unknown(name: str, table: dict[str, ModelEntry]) -> PlodError:
    entries = list(dict.fromkeys(table.values()))
    close = difflib.get_close_matches(_key(name), list(table), n=1, cutoff=0.6)
    hint = f" (did you mean {table[close[0]].name}?)" if close else ""
    return PlodError(f"unknown model {name!r}{hint}; choose one of {_valid_names(entries)}, "
                     "or a fitted model .json")


def _is_file(spec: str) -> bool:
    try:
        return Path(spec).is_file()
    except (OSError, ValueError):  # a name too long for a path, or with a NUL: not a file
        return False


def make_model(spec=None):
    """The CSF model named by ``spec`` (see the module docstring); a model instance is returned as is,
    None gives :func:`default_model`. PlodError for an unknown name, a class that needs arguments, a
    component that is not a CSF model, or a bad model file."""
    from ._base import CSFModel

    if spec is None:
        spec = DEFAULT_MODEL
    if isinstance(spec, eqx.Module):
        if not isinstance(spec, CSFModel):
            raise PlodError(f"make_model: a {type(spec).__name__} is not a CSF model")
        return spec
    if not isinstance(spec, (str, os.PathLike)):
        raise PlodError(f"make_model: expected a model name, file or instance, got {type(spec).__name__}")
    if isinstance(spec, os.PathLike) or _is_file(spec):
        return _from_file(spec)
    text = spec.strip()
    m = _COMPOSE.match(text)
    if m is None and text.lower().endswith(".json"):
        return _from_file(text)  # a missing file: PlodError
    if _key(text) == "default":
        text = DEFAULT_MODEL
    inner = None
    if m is not None:
        text, arg = m.group(1), m.group(2) if m.group(2) is not None else m.group(3)
        if not arg.strip():
            raise PlodError(f"model {spec!r}: empty inner model; write e.g. eccentric(manossakrison)")
        inner = make_model(arg.strip())
    table = _lookup()
    entry = table.get(_key(text))
    if entry is None:
        raise _unknown(text, table)
    if not entry.is_csf:
        raise PlodError(f"{entry.name} is not a CSF model (it loads from a model .json only); "
                        f"choose one of {_valid_names(dict.fromkeys(table.values()))}")
    return entry.build(inner)


_DEFAULT_CACHE: dict = {}


def default_model():
    """:data:`DEFAULT_MODEL` with its default constants (stelaCSF's published fit [MAC22]).

    One shared instance (models are immutable): building stelaCSF's constants costs about 2 ms, which
    ``optim.score`` would otherwise pay on every view. A new instance is built when
    :data:`DEFAULT_MODEL` or its registry entry changes."""
    entry = _lookup().get(_key(DEFAULT_MODEL))
    hit = _DEFAULT_CACHE.get(DEFAULT_MODEL)
    if hit is None or hit[0] != entry:
        _DEFAULT_CACHE.clear()
        hit = _DEFAULT_CACHE[DEFAULT_MODEL] = (entry, make_model(DEFAULT_MODEL))
    return hit[1]
