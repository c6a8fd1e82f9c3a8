"""Value checks that work under ``jit``: the one place techniques and materials turn a bad parameter into an error."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array


def checked(x: Array, name: str, *, positive: bool = False, finite: bool = True) -> Array:
    """``x`` unchanged, or an error naming ``name`` where it holds NaN, inf (unless ``finite=False``: +inf allowed)
    or a negative (with ``positive``: non-positive) value. Written so NaN trips it (``~(x >= 0)``, not ``x < 0``)."""
    bad = ~(x > 0) if positive else ~(x >= 0)
    if finite:
        bad = bad | ~jnp.isfinite(x)
    what = ("finite and " if finite else "") + ("> 0" if positive else ">= 0")
    return eqx.error_if(x, bad, f"{name} must be {what}")
