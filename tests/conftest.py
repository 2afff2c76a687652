"""Shared pytest fixtures: x64 switching, the optional ../shared data, hypothesis profiles."""

from __future__ import annotations

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


@pytest.fixture
def x64():
    """Run the test with 64-bit JAX (restored afterwards)."""
    old = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", old)


@pytest.fixture(params=["float32", "float64"])
def dtype(request):
    """Parametrise a test over float32 and float64 (x64 switched on for float64)."""
    old = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", request.param == "float64")
    try:
        yield request.param
    finally:
        jax.config.update("jax_enable_x64", old)


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    """``../shared`` (or ``$PLOD_SHARED``); the test is skipped when it is absent."""
    if not SHARED.is_dir():
        pytest.skip("../shared data not present")
    return SHARED
