"""The whole-frame formulations' entry points (``burley_gpu_impl``, ``separable_gpu_impl``): each picks the XLA
gather (``_burley_gpu``, ``_separable_gpu``) or the Pallas kernel (``_pallas``, built on those modules' per-sample
and per-tap terms). Here, above all three, so none of them imports another that imports it back."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array

from .._materials import BurleyMaterial
from .._scene import Buffers, Camera
from ._burley_gpu import gather_burley, pixel_planes, sample_pattern
from ._common import _finish, _prepare, _work_dtype
from ._pallas import burley_pallas, separable_pass_pallas
from ._separable_gpu import gather_pass, pass_inputs


@eqx.filter_jit
def burley_gpu_impl(buffers: Buffers, material: BurleyMaterial, camera: Camera, samples: int, albedo_mode: str,
                    interpolation: str, min_footprint_px: float, weight_channels: int, impl: str) -> Array:
    """``burley`` in the whole-frame formulation: ``impl`` "xla-gpu" (``gather_burley``) or "pallas"."""
    dtype = _work_dtype(buffers.irradiance.dtype)
    prep = _prepare(buffers, material.albedo, albedo_mode, dtype)
    h, w = buffers.depth.shape
    pix, active = pixel_planes(buffers, material, camera, prep, min_footprint_px, weight_channels, dtype)
    sample_u, sample_theta = sample_pattern(samples, dtype)
    kw = dict(height=h, width=w, mm_per_unit=camera.mm_per_unit.astype(dtype), interpolation=interpolation,
              weight_channels=weight_channels)
    if impl == "pallas":
        out = burley_pallas(pix, active.reshape(h * w), sample_u, sample_theta, **kw)
    else:
        out = gather_burley(pix, sample_u, sample_theta, **kw)
    scattered = jnp.stack(out, axis=-1).reshape(h, w, 3)
    scattered = jnp.where(active[..., None], scattered, prep.irradiance)
    return _finish(buffers, prep, scattered)


@eqx.filter_jit
def separable_gpu_impl(buffers: Buffers, material, camera: Camera, taps: int, albedo_mode: str,
                       follow_surface: bool, interpolation: str, min_footprint_px: float,
                       kernel_groups: tuple[int, ...] | None, impl: str) -> Array:
    """``separable`` in the whole-frame formulation: ``impl`` "xla-gpu" (``gather_pass``) or "pallas"."""
    dtype = _work_dtype(buffers.irradiance.dtype)
    prep = _prepare(buffers, material.albedo, albedo_mode, dtype)
    p = pass_inputs(buffers, material, camera, prep, taps, min_footprint_px, kernel_groups, dtype)
    if impl == "pallas":
        run_pass = separable_pass_pallas
    else:
        run_pass = gather_pass
    e = p.e
    for axis in (2, 1):  # horizontal, then vertical
        e = run_pass(e, p.z, p.reach_px, p.scale, p.skip, p.rows, p.w_table, p.unit_offsets, axis=axis,
                     follow_surface=follow_surface, interpolation=interpolation)
    return _finish(buffers, prep, jnp.moveaxis(e, 0, -1))
