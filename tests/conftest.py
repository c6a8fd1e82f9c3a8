"""Strict test configuration (house style): x64 available for gradient checks, no silent rank promotion."""

import os

# Several tests shard frames over devices; the host platform must be split before jax initialises.
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=4")

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

import pathlib

import pytest

SHARED = pathlib.Path(__file__).resolve().parents[2] / "shared"
if not SHARED.exists():  # CI clones the repo with shared/ beside it; a developer checkout may nest differently
    SHARED = pathlib.Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture(autouse=True, scope="module")
def _fresh_compilation_caches():
    """Each test file starts from empty JAX caches: the compiled programs of 400 tests held in one process grew the
    run's memory until XLA's compiler crashed late in the suite (it passes alone)."""
    yield
    jax.clear_caches()


@pytest.fixture
def as_users_run_it():
    """The messages a user sees: the test run checks every annotation (``--jaxtyping-packages`` in pyproject.toml),
    which answers bad input before the library's own checks can; tests of those messages switch the checker off."""
    import jaxtyping

    jaxtyping.config.update("jaxtyping_disable", True)
    yield
    jaxtyping.config.update("jaxtyping_disable", False)


@pytest.fixture(scope="session")
def shared_dir() -> pathlib.Path:
    if not SHARED.exists():
        pytest.skip("../shared is not beside the checkout")
    return SHARED
