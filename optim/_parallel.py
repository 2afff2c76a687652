"""Two independent chains of whole-array numpy work run at once, one on a side thread.

numpy releases the GIL inside its large array loops (``take``, ufuncs and their ``accumulate``,
``nonzero``, copies), so a chain of a few such calls on arrays of 10^5-10^6 elements runs on a second
core from a thread while the caller's own chain runs on the first (``bincount`` and the Python between
calls do not release it). Written here because :mod:`concurrent.futures` gives the pool, not the policy:
one worker, made lazily per process (a forked child makes its own: the parent's worker thread does not
exist in it), and no thread at all where the process may use a single core (then :func:`beside` calls
the function at once, in the caller's thread). Used by :func:`optim.extract`
(``reports/scripts/ab_extract.py`` measures it).
"""

from __future__ import annotations

import concurrent.futures
import os
import threading

__all__ = ["beside", "usable_cores"]

_LOCK = threading.Lock()
_POOL: concurrent.futures.ThreadPoolExecutor | None = None
_POOL_PID: int | None = None


def usable_cores() -> int:
    """The cores this process may run on (its affinity mask, where the platform has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


class _Done:
    """A call already made, with the ``result()`` of a :class:`concurrent.futures.Future`."""

    def __init__(self, fn, args):
        self._value = self._error = None
        try:
            self._value = fn(*args)
        except BaseException as e:  # re-raised by result(), as a Future does
            self._error = e

    def result(self):
        if self._error is not None:
            raise self._error
        return self._value


def _side_pool():
    global _POOL, _POOL_PID
    if usable_cores() < 2:
        return None
    with _LOCK:
        if _POOL is None or _POOL_PID != os.getpid():
            _POOL = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="plod-side")
            _POOL_PID = os.getpid()
        return _POOL


def beside(fn, *args):
    """Start ``fn(*args)`` on the side thread and return its future (``.result()`` waits and returns
    the value or raises the exception); on a single usable core, call it now. ``fn`` must not itself
    wait on :func:`beside` (one worker) and must only read arrays the caller does not write meanwhile.
    Always call ``.result()``, also on error paths of the caller, so no work outlives the call."""
    pool = _side_pool()
    if pool is None:
        return _Done(fn, args)
    return pool.submit(fn, *args)
