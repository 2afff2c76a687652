"""Atomic file output shared by every package (pmetric <- optim <- experiments).

Outputs are written to a temporary file in the destination folder and moved into place with
``os.replace``, so a crash never leaves a half-written file and readers never see one.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, protect: tuple[str | os.PathLike, ...] = ()) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success move it onto ``path`` atomically.

    ``protect`` lists input files that must never be overwritten: a ``ValueError`` is raised before
    anything is written when ``path`` resolves to one of them.
    """
    dest = Path(path)
    for p in protect:
        if p is not None and Path(p).exists() and dest.exists() and os.path.samefile(dest, p):
            raise ValueError(f"refusing to overwrite the input file {str(p)!r}; choose another output path")
    dest.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=dest.suffix or ".tmp", dir=dest.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, dest)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def atomic_write_text(path: str | os.PathLike, text: str, **kw) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns the final path."""
    with atomic_path(path, **kw) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def atomic_write_bytes(path: str | os.PathLike, data: bytes, **kw) -> Path:
    """Write ``data`` to ``path`` atomically; returns the final path."""
    with atomic_path(path, **kw) as tmp:
        tmp.write_bytes(data)
    return Path(path)
