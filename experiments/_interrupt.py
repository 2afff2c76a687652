"""Ctrl-C for the ``plod`` commands: always stop, exit 130, commit no output (issue 13, item 5).

Python's default SIGINT handler raises ``KeyboardInterrupt`` wherever the main thread happens to be.
When that is inside a garbage-collector callback (JAX registers ``_xla_gc_callback``), a ``__del__``
method or code that swallows ``BaseException``, the interrupt is printed as "Exception ignored in
..." and lost: the run went on, wrote its outputs and exited 0.

:func:`install` replaces the handler with one that

* records the interrupt (:func:`seen`), so it can never be lost;
* during start-up (:func:`install` with ``early``) only records it: see there;
* raises ``KeyboardInterrupt`` only where it propagates: inside a gc callback or a ``__del__`` it
  does not raise but delivers the interrupt again 20 ms later (``_thread.interrupt_main``), until it
  lands in ordinary code;
* while :func:`guard` is active, makes ``pmetric``'s atomic writes refuse to commit
  (:func:`pmetric._atomic.add_commit_check`): a temporary file is removed instead of moved into
  place, whatever swallowed the exception.

:func:`guard` (used by ``experiments._runinfo.report_errors``) installs it for one command and
restores the previous handler afterwards. The console script installs it first thing, before the
heavy imports (JAX), so an interrupt during start-up is seen as well. An interrupt that comes after an
output file was moved into place leaves that file whole; the command still exits 130.

This module imports only the standard library, so installing it costs nothing.
"""

from __future__ import annotations

import _thread
import atexit
import contextlib
import gc
import os
import signal
import sys
import threading

__all__ = ["install", "guard", "seen", "check", "stop_raising", "exit_process", "Interrupted"]

#: delay (s) before an interrupt that arrived in a gc callback or __del__ is delivered again
REDELIVER_S = 0.02


class _State:
    seen = False  # a SIGINT arrived
    raising = True  # the handler raises KeyboardInterrupt (False once the command is stopping)
    installed = False  # our handler is the SIGINT handler
    early = False  # installed by the console script (kept across guard())
    generation = 0  # bumped whenever a command starts or stops: a late re-delivery is dropped


_state = _State()


class Interrupted(KeyboardInterrupt):
    """Raised at a safe point (an output commit, the end of a command) after a Ctrl-C was seen."""


def seen() -> bool:
    """True once a SIGINT arrived while the handler was installed."""
    return _state.seen


def check() -> None:
    """Raise :class:`Interrupted` (a ``KeyboardInterrupt``) when a SIGINT was seen."""
    if _state.seen:
        raise Interrupted()


def stop_raising() -> None:
    """The command is stopping (or done): later SIGINTs are only recorded, never raised."""
    _state.raising = False
    _state.generation += 1


def _swallowing_frame(frame) -> bool:
    """True when ``frame`` (or a caller) is a gc callback or a ``__del__``: an exception raised there
    is printed as "Exception ignored in ..." and lost."""
    codes = {getattr(cb, "__code__", None) for cb in gc.callbacks}
    codes.discard(None)
    while frame is not None:
        code = frame.f_code
        if code in codes or code.co_name == "__del__":
            return True
        frame = frame.f_back
    return False


def _redeliver(generation: int) -> None:
    if _state.installed and _state.raising and _state.generation == generation:
        _thread.interrupt_main(signal.SIGINT)


def _handler(signum, frame) -> None:
    _state.seen = True
    if not _state.raising:
        return
    if _swallowing_frame(frame):
        t = threading.Timer(REDELIVER_S, _redeliver, (_state.generation,))
        t.daemon = True
        t.start()
        return
    raise KeyboardInterrupt()


def install(*, early: bool = False) -> bool:
    """Make :func:`_handler` the SIGINT handler (main thread only); True when it is installed.

    ``early`` (the console script, before the heavy imports): SIGINTs are only recorded until
    :func:`guard` starts. A ``KeyboardInterrupt`` raised while a C extension initialises (jaxlib's
    ``_jax``) turns into "ImportError: Encountered an error while initializing the extension" or
    crashes the interpreter (measured: SIGINT 0.15 s into ``python -c "import jax"`` gave SIGSEGV);
    recorded instead, the interrupt stops the command as soon as the imports are done.
    """
    if threading.current_thread() is not threading.main_thread():
        return False
    if early:
        _state.raising = False
    signal.signal(signal.SIGINT, _handler)
    _state.installed = True
    _state.early = _state.early or early
    return True


def _commit_check() -> None:
    check()


@contextlib.contextmanager
def guard():
    """Install the handler for one command (see the module docstring); on leaving, the previous
    handler comes back (unless the console script installed ours) and the state is reset."""
    from pmetric._atomic import add_commit_check, remove_commit_check

    _state.generation += 1
    early = _state.early and _state.installed
    ours = False
    prev = None
    if early:
        _state.raising = True  # start-up is over; report_errors checks for an interrupt seen during it
    elif threading.current_thread() is threading.main_thread():
        prev = signal.getsignal(signal.SIGINT)  # None: a handler not set from Python (kept as SIG_DFL)
        _state.seen, _state.raising = False, True
        ours = install()
    add_commit_check(_commit_check)
    try:
        yield
    finally:
        _state.generation += 1
        remove_commit_check(_commit_check)
        if ours:
            signal.signal(signal.SIGINT, prev if prev is not None else signal.default_int_handler)
            _state.installed = False
            _state.seen, _state.raising = False, True


def exit_process(code: int) -> None:  # pragma: no cover - ends the process (tests run it in a subprocess)
    """End the process with status ``code``, also after a handled Ctrl-C.

    CPython (3.11) remembers a ``KeyboardInterrupt`` that left any ``exec`` of a string (dataclass and
    namedtuple definitions run one: an interrupt during a lazy import of an ``eqx.Module``), even one
    handled later, and under ``python -m`` it then ends the process by SIGINT after ``sys.exit``
    (status -2 instead of 130; ``tests/test_fuzz.py`` shows it). For status 130 the exit handlers run
    and the streams are flushed here, and the process ends with ``os._exit``, which nothing overrides.
    """
    if code != 130:
        sys.exit(code)
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(130)
