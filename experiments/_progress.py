"""Rich progress bars for the library's ``progress`` callbacks (the library itself prints nothing).

Library functions that run long take ``progress=`` a callable ``progress(stage: str, done: int,
total: int)`` (``optim.build_tree``: one call per build stage). :func:`rich_progress` yields such a
callback that draws one rich bar; :func:`call_with_progress` wraps a single call.

    with rich_progress("build tree") as cb:
        tree = optim.build_tree(v, f, progress=cb)
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

__all__ = ["rich_progress", "call_with_progress"]

ProgressCallback = Callable[[str, int, int], None]


@contextlib.contextmanager
def rich_progress(description: str = "", *, enabled: bool = True, console=None,
                  transient: bool = True) -> Iterator[ProgressCallback | None]:
    """Yield a callback ``cb(stage, done, total)`` that draws a rich progress bar labelled
    ``description: stage`` at ``done`` of ``total`` (None when not ``enabled`` or when the console is
    not a terminal: a bar in a log or a pipe is noise). ``console``: a ``rich.console.Console``
    (default: one on stderr, so machine-readable stdout stays clean)."""
    from rich.console import Console
    from rich.progress import Progress

    console = console or Console(stderr=True)
    if not enabled or not console.is_terminal:
        yield None
        return
    with Progress(console=console, transient=transient) as prog:
        task = prog.add_task(description, total=None)

        def callback(stage: str, done: int, total: int) -> None:
            label = f"{description}: {stage}" if description else stage
            prog.update(task, description=label, completed=done, total=total)

        yield callback


def call_with_progress(fn, *args, progress: bool = True, description: str = "", **kwargs):
    """``fn(*args, progress=cb, **kwargs)`` with ``cb`` from :func:`rich_progress` (``progress=False``:
    ``progress=None``, nothing drawn)."""
    with rich_progress(description or getattr(fn, "__name__", ""), enabled=progress) as cb:
        return fn(*args, progress=cb, **kwargs)
