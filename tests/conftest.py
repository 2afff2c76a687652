"""Shared pytest fixtures: x64 switching, the optional ../shared data, hypothesis profiles."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import jax
import pytest
from hypothesis import HealthCheck, settings

settings.register_profile(
    "plod", deadline=None, max_examples=40, suppress_health_check=[HealthCheck.too_slow], derandomize=True
)
settings.register_profile("thorough", deadline=None, max_examples=400)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "plod"))

ROOT = Path(__file__).resolve().parent.parent
SHARED = Path(os.environ.get("PLOD_SHARED", ROOT.parent / "shared"))


@contextlib.contextmanager
def x64_mode(enabled: bool = True):
    """Switch JAX's 64-bit mode for a block (restored afterwards); usable inside hypothesis tests,
    where function-scoped fixtures do not apply per example (``from conftest import x64_mode``)."""
    old = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", enabled)
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", old)


@pytest.fixture
def x64():
    """Run the test with 64-bit JAX (restored afterwards)."""
    with x64_mode(True):
        yield


@pytest.fixture(params=["float32", "float64"])
def dtype(request):
    """Parametrise a test over float32 and float64 (x64 switched on for float64)."""
    with x64_mode(request.param == "float64"):
        yield request.param


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """``../shared`` (or ``$PLOD_SHARED``); the test is skipped when it is absent."""
    if not SHARED.is_dir():
        pytest.skip("../shared data not present")
    return SHARED
