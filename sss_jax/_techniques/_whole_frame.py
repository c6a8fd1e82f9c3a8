"""The whole-frame separable formulation's entry point (``separable_gpu_impl``): it picks the XLA gather
(``_separable_gpu``) or the Pallas kernel (``_pallas``, built on that module's per-tap term). Here, above both, so
neither imports the other back."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._scene import Camera, Buffers
from ._common import _finish, _prepare, _work_dtype
from ._pallas import separable_pass_pallas
from ._separable_gpu import gather_pass, pass_inputs


@eqx.filter_jit
def separable_gpu_impl(buffers: Buffers, material, camera: Camera, taps: int, albedo_mode: str,
                       follow_surface: bool, interpolation: str, min_footprint_px: float,
                       kernel_groups: tuple[int, ...] | None, impl: str, border: str = "renormalise",
                       origin: tuple[int, int] = (0, 0), frame_shape: tuple[int, int] | None = None) -> Array:
    """``separable`` in the whole-frame formulation: ``impl`` "gather" (``gather_pass``) or "pallas"; ``origin``
    and ``frame_shape`` place a tile in its frame (the border and the cut of wide kernels follow the frame)."""
    dtype = _work_dtype(buffers.irradiance.dtype)
    prep = _prepare(buffers, material.albedo, albedo_mode, dtype)
    frame_shape = tuple(buffers.depth.shape) if frame_shape is None else tuple(frame_shape)
    p = pass_inputs(buffers, material, camera, prep, taps, min_footprint_px, kernel_groups, dtype, frame_shape)
    run_pass = separable_pass_pallas if impl == "pallas" else gather_pass
    e = p.e
    for axis in (2, 1):  # horizontal, then vertical
        e = run_pass(e, p.z, p.reach_px, p.scale, p.skip, p.rows, p.w_table, p.unit_offsets, p.cut_table, axis=axis,
                     follow_surface=follow_surface, interpolation=interpolation, border=border,
                     origin_along=int(origin[axis - 1]), frame_length=int(frame_shape[axis - 1]))
    return _finish(buffers, prep, jnp.moveaxis(e, 0, -1))
