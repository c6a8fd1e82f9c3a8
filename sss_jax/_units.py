"""The one conversion between lengths of materials (mm) and screen lengths (pixels).

A length ``L`` millimetres long, lying in a plane facing the camera at planar view depth ``z`` (scene units),
covers ``L / mm_per_unit * focal_px / z`` pixels under a pinhole camera. Every pass, fit and report calls this.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ._checks import check_host_range
from ._custom_types import ParamLike


def px_per_mm(depth: ParamLike, *, focal_px: ParamLike, mm_per_unit: ParamLike) -> Array:
    """Pixels covered by one millimetre at planar depth ``depth`` (scene units).

    Depth ``inf`` (no surface) gives 0 px/mm; depth 0 or below, or NaN, also gives 0 (a footprint cannot be
    projected there), so the result is always finite and its gradient NaN-free.
    """
    depth = jnp.asarray(depth)
    if not jnp.issubdtype(depth.dtype, jnp.floating):  # an integer depth: the lengths' float, not theirs cut to it
        depth = depth.astype(jnp.result_type(float))
    _check_positive("focal_px", focal_px)
    _check_positive("mm_per_unit", mm_per_unit)
    focal_px = jnp.asarray(focal_px, dtype=depth.dtype)
    mm_per_unit = jnp.asarray(mm_per_unit, dtype=depth.dtype)
    ok = jnp.isfinite(depth) & (depth > 0)
    safe_depth = jnp.where(ok, depth, jnp.ones_like(depth))  # double where: no inf/0 in the division below
    return jnp.where(ok, focal_px / (safe_depth * mm_per_unit), jnp.zeros_like(depth))


def _check_positive(name: str, value) -> None:
    """A host value (Python, NumPy) must be positive and finite; JAX arrays are the passes' (their ``Camera``
    checked them), not read back here (a device read per call)."""
    if isinstance(value, (bool, np.bool_, str)):
        raise TypeError(f"{name} must be a positive number, got {value!r}")
    if isinstance(value, (int, float, np.ndarray, np.number)):
        check_host_range(value, name, low_open=True)


def mm_to_px(length_mm: ParamLike, depth: ParamLike, *, focal_px: ParamLike, mm_per_unit: ParamLike) -> Array:
    """Length in pixels of ``length_mm`` millimetres at planar depth ``depth`` (scene units).

    ``px = length_mm / mm_per_unit * focal_px / depth``. Broadcasting follows NumPy's rules.
    """
    length_mm = jnp.asarray(length_mm)
    return length_mm * px_per_mm(depth, focal_px=focal_px, mm_per_unit=mm_per_unit)
