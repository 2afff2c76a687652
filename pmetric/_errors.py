"""The one error type of plod: :class:`PlodError`.

Every check of user input in ``pmetric``, ``optim`` and ``experiments`` (a bad mesh, a NaN, an
out-of-range index, an unknown option or model name, a malformed CSV, config or model file) raises
``PlodError``. It subclasses ``ValueError``, so ``except ValueError`` keeps working; the ``plod``
command line prints it as one line (``plod CMD: error: ...``) and exits with status 2.
"""

from __future__ import annotations

__all__ = ["PlodError"]


class PlodError(ValueError):
    """An error caused by the caller's input (a value, option, file or model); the message names it."""
