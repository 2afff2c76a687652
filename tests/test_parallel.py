"""optim._parallel: the side thread's results and errors, its single-core path, and a forked child."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import optim._parallel as P


@pytest.mark.parametrize("cores", [1, 2])
def test_beside_returns_the_value_and_raises_the_error(cores, monkeypatch):
    monkeypatch.setattr(P, "usable_cores", lambda: cores)
    a = np.arange(1_000_000, dtype=np.int64)
    fut = P.beside(np.take, a, np.array([3, 999_999, 0]))
    assert fut.result().tolist() == [3, 999_999, 0]
    bad = P.beside(np.take, a, np.array([1_000_000]))  # out of range: numpy's IndexError, not a hang or None
    with pytest.raises(IndexError):
        bad.result()
    assert P.beside(lambda x: x + 1, 41).result() == 42  # the worker is still usable after an error


def test_beside_runs_on_another_thread_only_with_two_cores(monkeypatch):
    import threading

    me = threading.get_ident()
    monkeypatch.setattr(P, "usable_cores", lambda: 1)
    assert P.beside(threading.get_ident).result() == me
    monkeypatch.setattr(P, "usable_cores", lambda: 2)
    assert P.beside(threading.get_ident).result() != me


def test_beside_works_in_a_forked_child():
    """A child forked after the side thread started makes its own (the parent's thread does not exist
    in it; reusing the parent's pool would wait forever)."""
    path = Path(P.__file__)
    code = textwrap.dedent(f"""
        import importlib.util, os, sys
        spec = importlib.util.spec_from_file_location("par", {str(path)!r})
        P = importlib.util.module_from_spec(spec); spec.loader.exec_module(P)
        P.usable_cores = lambda: 2
        assert P.beside(lambda: 1).result() == 1  # the parent's worker exists now
        pid = os.fork()
        if pid == 0:
            os._exit(0 if P.beside(lambda: 7).result() == 7 else 3)
        _, status = os.waitpid(pid, 0)
        sys.exit(os.waitstatus_to_exitcode(status))
    """)
    r = subprocess.run([sys.executable, "-c", code], timeout=60, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
