"""Output paths of the ``plod`` commands, checked before any work is done (issue 13).

Every command calls :func:`check_output` for each path it will write (mesh, render PNG, JSON model,
CSV) before it reads data, builds a tree or fits anything, so a bad path fails at once with one line
naming the flag, and an input file is never overwritten.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Iterable

from pmetric import PlodError

MESH_SUFFIXES = (".ply", ".obj", ".off", ".stl", ".glb")  # what optim.save_mesh writes


def _same(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def model_files(spec) -> list[Path]:
    """The existing files a model spec reads: the spec itself, or the files inside a composition
    (``"eccentric( a.json )"``: ``a.json``), stripped as ``pmetric.make_model`` strips them, so that an
    output check sees every input a spec names (before, a wrapped or space-padded path slipped past it)."""
    if spec is None:
        return []
    text = str(spec)
    out = []
    for token in [text, *text.replace("(", ",").replace(")", ",").split(",")]:
        q = Path(token.strip())
        if token.strip() and q.is_file() and q not in out:
            out.append(q)
    return out


def check_mesh_input(path) -> Path:
    """``Path(path)`` of an input mesh file that exists; PlodError saying what it is otherwise (a folder
    was reported as "not found")."""
    p = Path(path)
    if p.is_dir():
        raise PlodError(f"{str(p)!r} is a directory, not a mesh file")
    if not p.is_file():
        raise PlodError(f"mesh file not found: {str(p)!r}")
    return p


def check_output(flag: str, path, *, suffixes: Iterable[str], inputs: Iterable = ()) -> Path:
    """``Path(path)`` once it is a writable output; else ``PlodError`` naming ``flag``.

    Checks, in order: the path is not an existing directory; it is none of ``inputs`` (paths, or
    ``(label, path)`` pairs naming them in the message; paths that are not files are ignored, e.g. model
    names); the suffix is one of ``suffixes``
    (case-insensitive); its parent is an existing directory in which a file can be created (probed with a
    temporary file that is removed at once).
    """
    out = Path(path)
    sfx = tuple(s.lower() for s in suffixes)
    if out.is_dir():
        raise PlodError(f"{flag} {str(out)!r} is a directory; give a file name")
    for inp in inputs:
        label, inp = inp if isinstance(inp, tuple) else ("an input file", inp)
        if inp is None:
            continue
        q = Path(inp)
        if q.is_file() and _same(out, q):
            raise PlodError(f"{flag} {str(out)!r} is {label}; refusing to overwrite it, choose another path")
    if out.suffix.lower() not in sfx:
        what = repr(out.suffix) if out.suffix else "a name without suffix"
        raise PlodError(f"{flag} {str(out)!r}: cannot write {what}; use {', '.join(sfx)}")
    parent = out.parent
    if not parent.exists():
        raise PlodError(f"{flag} {str(out)!r}: folder {str(parent)!r} does not exist")
    if not parent.is_dir():
        raise PlodError(f"{flag} {str(out)!r}: {str(parent)!r} is not a folder")
    try:
        fd, probe = tempfile.mkstemp(prefix=".plod-probe-", dir=parent)
    except OSError as exc:
        raise PlodError(f"{flag} {str(out)!r}: cannot write in folder {str(parent)!r} "
                        f"({exc.strerror or type(exc).__name__})") from None
    os.close(fd)
    os.unlink(probe)
    return out
