"""Atomic file output shared by every package (pmetric <- optim <- experiments).

Outputs are written to a temporary file in the destination folder and moved into place with
``os.replace``, so a crash never leaves a half-written file and readers never see one.

Temporary files are named ``.NAME.plod-tmp-HOST-PID-RANDOM[SUFFIX]`` (``NAME`` the target's file
name, ``HOST`` a 6-hex tag of the host name, ``PID`` the writing process, ``SUFFIX`` the target's
suffix, kept so writers that pick a format from the name still work). They are removed on any
exception (``KeyboardInterrupt`` included). A process killed outright (SIGKILL, power loss) cannot
clean up, so every write first removes the stale temporary files *of the same target* in that
folder: those of this host whose process is gone, and any older than :data:`STALE_AFTER_S`.

Commit checks: a program may register callables (:func:`add_commit_check`) that every write calls
before it creates its temporary file and again just before it moves the file into place; one that
raises stops the write (the temporary file is removed, the target left as it was). The ``plod``
command line registers one that raises ``KeyboardInterrupt`` once Ctrl-C was pressed
(``experiments._interrupt``), so no output is committed after an interrupt, even one that something
swallowed. The library itself registers none.

Permissions: a new file gets ``0666 & ~umask`` (like ``open(path, "w")``); overwriting an existing
file keeps that file's permission bits.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import secrets
import socket
import stat
import time
from pathlib import Path
from typing import Iterator

from ._errors import PlodError

__all__ = ["atomic_path", "atomic_write_text", "atomic_write_bytes", "protect_paths", "STALE_AFTER_S", "TMP_TAG",
           "add_commit_check", "remove_commit_check", "remove_stale_temps", "remove_stale_temps_in"]

TMP_TAG = ".plod-tmp-"
"""Marker in every temporary file name of :func:`atomic_path`."""

STALE_AFTER_S = 3600.0
"""A temporary file untouched for this long (s) is stale whatever its PID (PID reuse, other hosts)."""


_COMMIT_CHECKS: list = []


def add_commit_check(fn) -> None:
    """Register ``fn()`` to be called before every write creates and commits a file (see the module
    docstring); an exception it raises stops that write."""
    if fn not in _COMMIT_CHECKS:
        _COMMIT_CHECKS.append(fn)


def remove_commit_check(fn) -> None:
    """Undo :func:`add_commit_check` (no error when ``fn`` is not registered)."""
    with contextlib.suppress(ValueError):
        _COMMIT_CHECKS.remove(fn)


def _run_commit_checks() -> None:
    for fn in tuple(_COMMIT_CHECKS):
        fn()


def _host_tag() -> str:
    return hashlib.sha1(socket.gethostname().encode("utf-8", "replace")).hexdigest()[:6]


def _tmp_regex(name: str) -> re.Pattern:
    return re.compile(r"\." + re.escape(name) + re.escape(TMP_TAG) + r"([0-9a-f]{6})-(\d+)-[0-9a-f]+.*\Z", re.S)


def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    except OSError:
        return True  # unknown: keep the file (the age rule still applies)
    return True


def _sweep(folder: Path, rx: re.Pattern, now: float | None) -> list[Path]:
    host = _host_tag()
    me = os.getpid()
    now = time.time() if now is None else now
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for e in entries:
        m = rx.match(e.name)
        if m is None:
            continue
        try:
            if not e.is_file(follow_symlinks=False):
                continue
            age = now - e.stat(follow_symlinks=False).st_mtime
        except OSError:
            continue
        tag, pid = m.group(1), int(m.group(2))
        dead = tag == host and pid != me and not _pid_alive(pid)
        if dead or age > STALE_AFTER_S:
            with contextlib.suppress(OSError):
                os.unlink(e.path)
                removed.append(Path(e.path))
    return removed


def remove_stale_temps(dest: str | os.PathLike, *, now: float | None = None) -> list[Path]:
    """Remove the stale temporary files of target ``dest`` (see the module docstring); returns them.

    Never raises for files it cannot remove or folders it cannot list.
    """
    dest = Path(dest)
    return _sweep(dest.parent, _tmp_regex(dest.name), now)


_ANY_TMP = re.compile(r"\..+?" + re.escape(TMP_TAG) + r"([0-9a-f]{6})-(\d+)-[0-9a-f]+.*\Z", re.S)


def remove_stale_temps_in(folder: str | os.PathLike, *, now: float | None = None) -> list[Path]:
    """Remove the stale temporary files of *every* target in ``folder`` (same rules as
    :func:`remove_stale_temps`; only names of this module's pattern are touched). For folders plod
    owns (its cache), where the target of a killed write may never be written again."""
    return _sweep(Path(folder), _ANY_TMP, now)


def _new_temp(dest: Path) -> Path:
    """Create (O_EXCL) an empty temporary file beside ``dest``, mode ``0666 & ~umask``."""
    prefix = f".{dest.name}{TMP_TAG}{_host_tag()}-{os.getpid()}-"
    for _ in range(100):
        tmp = dest.parent / f"{prefix}{secrets.token_hex(4)}{dest.suffix}"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return tmp
    raise FileExistsError(f"cannot create a temporary file beside {str(dest)!r}")


def protect_paths(protect) -> tuple:
    """``protect`` as a tuple of paths: one path (a ``str`` or ``os.PathLike``) is one file
    (not its characters), ``None`` none, else an iterable of paths (``None`` entries are skipped).
    PlodError (one line) for anything else."""
    if protect is None:
        return ()
    if isinstance(protect, (str, os.PathLike)):
        return (protect,)
    try:
        items = tuple(protect)
    except TypeError:
        raise PlodError(f"protect must be a path or a sequence of paths, got {type(protect).__name__}") from None
    for p in items:
        if p is not None and not isinstance(p, (str, os.PathLike)):
            raise PlodError(f"protect must be a path or a sequence of paths, got an entry of type {type(p).__name__}")
    return tuple(p for p in items if p is not None)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, *, protect: str | os.PathLike | tuple[str | os.PathLike, ...] = ()
                ) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success move it onto ``path`` atomically.

    ``protect`` lists input files that must never be overwritten (one path or a sequence of paths,
    :func:`protect_paths`): a :class:`PlodError` (a ``ValueError``) is raised before anything is
    written when ``path`` resolves to one of them, or is a directory, or lies below a file.
    The caller writes the temporary path (by name: it already exists, empty). A new ``path`` gets
    mode ``0666 & ~umask``; an existing one keeps its permission bits. On any exception the
    temporary file is removed and ``path`` is left as it was.
    """
    dest = Path(path)
    for p in protect_paths(protect):
        if Path(p).exists() and dest.exists() and os.path.samefile(dest, p):
            raise PlodError(f"refusing to overwrite the input file {str(p)!r}; choose another output path")
    if dest.is_dir():
        raise PlodError(f"cannot write {str(dest)!r}: it is a directory; give a file name")
    _run_commit_checks()
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise PlodError(f"cannot write {str(dest)!r}: a file is in the way of its folder "
                        f"{str(dest.parent)!r}") from None
    remove_stale_temps(dest)
    tmp_path: Path | None = None
    try:
        tmp_path = _new_temp(dest)
        yield tmp_path
        _run_commit_checks()
        try:
            mode = stat.S_IMODE(os.stat(dest).st_mode)
        except FileNotFoundError:
            mode = None
        except OSError:
            mode = None
        if mode is not None:
            os.chmod(tmp_path, mode)
        os.replace(tmp_path, dest)
    except BaseException:
        if tmp_path is not None:
            with contextlib.suppress(OSError):
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
