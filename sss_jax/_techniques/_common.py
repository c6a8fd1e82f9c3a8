"""What every technique shares: which pixels take part, the material row per pixel, the albedo split, value checks
that work under ``jit``, interpolated fetches and NaN-safe elementary functions.

A pixel takes part when it has a surface (finite positive depth) and, if a ``material_id`` buffer is given, a non-zero
id; every other pixel passes through untouched (output = input irradiance). The output of an SSS pixel is
``albedo * scattered irradiance`` (``albedo_mode="post"``) or, with ``albedo_mode="pre_post"``,
``sqrt(albedo) * scatter(sqrt(albedo) * irradiance)`` (texture detail survives the blur). Albedo comes from the buffer
when present, else from the material. Work happens in at least float32 and the result has the irradiance's dtype.
"""

from __future__ import annotations

import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._checks import clamp
from .._scene import Buffers, Camera, on_host, passed, surface_mask, validate_buffers

ALBEDO_MODES = ("post", "pre_post")


def _work_dtype(dtype) -> jnp.dtype:
    return jnp.promote_types(dtype, jnp.float32)


def _check_albedo_mode(mode: str) -> None:
    if mode not in ALBEDO_MODES:
        raise ValueError(f"albedo_mode={mode!r} is not one of {ALBEDO_MODES}")


def check_one_image(name: str, buffers: Buffers, materials: int | None = None, *, camera: Any = Camera) -> None:
    """What every technique checks before tracing: one image (a batch is vmapped), not an empty one, and, where the
    buffers are concrete and on the host (reading them costs no transfer and no wait), the values that would make the
    result wrong without a word (``validate_buffers(..., physical=False)``: a NaN irradiance would spread to every
    pixel that reads it, an id past the ``materials`` rows take the last row's parameters). Under ``jit``/``vmap``
    and on an accelerator nothing is read back: call ``validate_buffers`` there. ``camera``, where given: a
    ``Camera`` (a TypeError naming the argument, not an AttributeError from inside)."""
    if not isinstance(buffers, Buffers):
        raise TypeError(f"{name}: buffers must be a Buffers, got {type(buffers).__name__}")
    if camera is not Camera and not isinstance(camera, Camera):
        raise TypeError(f"{name}: camera must be a Camera (focal length in px, mm per scene unit), got "
                        f"{type(camera).__name__}")
    if buffers.irradiance.ndim != 3:
        raise ValueError(f"{name} takes one image (H, W, 3); vmap for a batch, got {buffers.irradiance.shape}")
    if 0 in buffers.depth.shape:
        raise ValueError(f"{name}: the image is empty ({buffers.depth.shape[1]}x{buffers.depth.shape[0]} pixels)")
    if passed(buffers, materials, physical=False):  # checked before (validate_buffers remembers JAX arrays)
        return
    if _is_concrete(buffers) and all(on_host(leaf) for leaf in jax.tree.leaves(buffers)):
        validate_buffers(buffers, materials=materials, name=name, physical=False)


def _sss_mask(buffers: Buffers) -> Array:
    return sss_mask_of(buffers.depth, buffers.material_id)


def sss_mask_of(depth: Array | np.ndarray, material_id: Array | np.ndarray | None) -> Array | np.ndarray:
    """The pixels with SSS: a surface (``surface_mask``) with a material (id > 0, where ids are given). Operators
    only: NumPy planes give a NumPy mask (host side, no dispatch to wait behind a device's queue)."""
    mask = surface_mask(depth)
    if material_id is not None:
        mask = mask & (material_id > 0)
    return mask


def _material_rows(buffers: Buffers, count: int) -> Array:
    """Row of the material table used by each pixel (id k -> row k-1; with one material every id uses it)."""
    if buffers.material_id is None or count == 1:
        return jnp.zeros(buffers.depth.shape, jnp.int32)
    return jnp.clip(buffers.material_id.astype(jnp.int32) - 1, 0, count - 1)


class _Prepared(eqx.Module):
    irradiance: Array  # what gets scattered (after the pre-scatter albedo, if any), work dtype
    depth: Array
    valid: Array
    rows: Array
    albedo_out: Array  # what multiplies the scattered irradiance


def _prepare(buffers: Buffers, material_albedo: Array, albedo_mode: str, dtype) -> _Prepared:
    valid = _sss_mask(buffers)
    rows = _material_rows(buffers, material_albedo.shape[0])
    albedo = buffers.albedo if buffers.albedo is not None else material_albedo.astype(dtype)[rows]
    albedo = clamp(albedo.astype(dtype), 0.0, 1.0)
    # pixels that take no part hold nothing a neighbour could read: no NaN or inf depth, no stray irradiance
    e = jnp.where(valid[..., None], buffers.irradiance.astype(dtype), 0.0)
    depth = jnp.where(valid, buffers.depth.astype(dtype), 0.0)
    if albedo_mode == "pre_post":
        root = jnp.sqrt(albedo)
        e, albedo = e * root, root
    return _Prepared(irradiance=e, depth=depth, valid=valid, rows=rows, albedo_out=albedo)


def as_output(out: Array, dtype) -> Array:
    """``out`` (the work dtype) as the buffers' dtype: held to that dtype's finite range where it is narrower (half
    holds at most 65504; light a translucency adds to 60000 turned to inf, as the CLI's half writer clamps it), a
    plain cast where it is not (no operation in the program)."""
    dtype = jnp.dtype(dtype)
    if jnp.issubdtype(dtype, jnp.floating) and jnp.finfo(dtype).max < jnp.finfo(out.dtype).max:
        big = jnp.finfo(dtype).max
        out = jnp.clip(out, -big, big)
    return out.astype(dtype)


def _finish(buffers: Buffers, prep: _Prepared, scattered: Array) -> Array:
    out = prep.albedo_out * scattered
    out = jnp.where(prep.valid[..., None], out, buffers.irradiance.astype(out.dtype))
    return as_output(out, buffers.irradiance.dtype)


def _corners(flat: Array, height: int, width: int, y: Array, x: Array, *, interpolation: str):
    """The pixels a fetch at fractional coordinates (pixel centres at integers) reads from ``flat (H*W, K)``, with
    their interpolation weights; pixels outside the image get weight 0."""
    # clip first: huge or NaN offsets must not overflow the integer cast
    x = jnp.clip(jnp.nan_to_num(x, nan=-4.0), -4.0, width + 3.0)
    y = jnp.clip(jnp.nan_to_num(y, nan=-4.0), -4.0, height + 3.0)
    if interpolation == "nearest":
        corners = [(jnp.round(y), jnp.round(x), None)]
    else:
        x0, y0 = jnp.floor(x), jnp.floor(y)
        fx, fy = x - x0, y - y0
        corners = [
            (y0, x0, (1 - fy) * (1 - fx)),
            (y0, x0 + 1, (1 - fy) * fx),
            (y0 + 1, x0, fy * (1 - fx)),
            (y0 + 1, x0 + 1, fy * fx),
        ]
    out = []
    for yi, xi, wgt in corners:
        inside = (xi >= 0) & (xi <= width - 1) & (yi >= 0) & (yi <= height - 1)
        idx = jnp.clip(yi, 0, height - 1).astype(jnp.int32) * width + jnp.clip(xi, 0, width - 1).astype(jnp.int32)
        w = inside.astype(flat.dtype) if wgt is None else jnp.where(inside, wgt, 0.0)
        out.append((jnp.take(flat, idx, axis=0), w))
    return out



def _pack(e: Array, depth: Array, valid: Array) -> Array:
    """(H*W, 5): irradiance and depth zeroed where invalid (no inf * 0), and the validity itself."""
    v = valid.astype(e.dtype)
    z = jnp.where(valid, depth, 0.0)
    e = jnp.where(valid[..., None], e, 0.0)
    return jnp.concatenate([e, z[..., None], v[..., None]], axis=-1).reshape(-1, 5)



def _safe_sqrt(x: Array) -> Array:
    """sqrt with a finite gradient at 0 (double where)."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)



def _safe_log(x: Array) -> Array:
    pos = x > 0
    return jnp.where(pos, jnp.log(jnp.where(pos, x, 1.0)), 0.0)



def _is_concrete(*trees) -> bool:
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(trees))


def check_seed(owner: str, seed):
    """A concrete ``seed`` checked, an integer in [0, 2**32) (the passes hash it as a uint32): the error names the
    owner and the value (a seed of -1, 1.5 or 2**32 would wrap, round or overflow inside JAX). A traced one passes."""
    if not _is_concrete(seed):
        return seed
    try:
        ok = (np.ndim(seed) == 0 and not isinstance(seed, (bool, np.bool_)) and np.asarray(seed).dtype != bool
              and float(seed) == int(seed) and 0 <= int(seed) < 2**32)
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        raise ValueError(f"{owner}: seed must be an integer in [0, 2**32), got {seed!r}")
    return seed


def _as_seed(seed):
    """A seed as the passes take it, uint32: a concrete one stays a NumPy value until a jitted call takes it (an
    eager ``jnp`` conversion is a device dispatch of its own, ~0.1-0.3 ms of a call's host time), a traced one is
    converted in its trace."""
    if _is_concrete(seed):
        return np.asarray(seed).astype(np.uint32)
    return jnp.asarray(seed).astype(jnp.uint32)


# Footprint below which a pixel keeps its local shading (px): the paper's Fig. 1, scattering narrower than a pixel
# is invisible. The footprint is the radius holding 99% of the widest channel's energy, projected at the pixel.
MIN_FOOTPRINT_PX = 0.5


# Out of the frame: light that a profile carries past the image's edge leaves (it is not pushed back onto the pixels
# inside). A pass normalises each pixel by the profile's full energy, of which the part past the edge counts as dark
# surface at the pixel's own depth; pixels without a surface inside the frame, and depth steps, keep what each
# technique does with them (dropped from the normalisation; "follow the surface"). This is the analytic piece:
# the reference adds ``1 - frame_energy_fraction`` to its normalisation, burley counts its samples that land
# outside (and the energy past the image diagonal), separable counts its taps that land outside as dark.
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(16)

# What the passes assume beyond the frame: "leaves" (default; the rule above: nothing there, light scattered out is
# lost) or "renormalise" (the kernel renormalised over what landed inside, as if the surface beyond looked like the
# inside: what the passes did before issue #18, and the better model where a lit surface is cut by the frame edge,
# e.g. a close-up, whose outside sends light in as much as the inside sends out)
BORDERS = ("leaves", "renormalise")


def _check_border(border: str) -> None:
    if border not in BORDERS:
        raise ValueError(f"border={border!r} is not one of {BORDERS}")


def frame_energy_fraction(cdf, rows: Array, cols: Array, height: int, width: int, pixel_mm: Array) -> Array:
    """Fraction of a radial profile's energy, centred on pixel (``rows``, ``cols``) of a ``height`` x ``width``
    frame (pixel centres at integers, the frame spanning ``[-0.5, height - 0.5] x [-0.5, width - 0.5]``), that falls
    inside the frame, on a plane where a pixel is ``pixel_mm`` wide. ``cdf(r_mm)`` returns the energy inside radius
    r, shape ``rows.shape + (C,)``.

    Exact for a radial profile up to quadrature: the frame, seen from the pixel, is 8 right triangles (apex at the
    pixel, one leg the perpendicular to a side of length a, the other along the side, length b), and a triangle
    holds ``(1/2pi) int_0^atan(b/a) CDF(a / cos phi) dphi``: 16 Gauss-Legendre nodes over ``phi`` up to pi/4, and 16
    over ``t = log tan phi`` beyond (``dphi = dt / (2 cosh t)``), where a long side seen from close by would leave
    the angle rule too few nodes near pi/2."""
    dtype = pixel_mm.dtype
    nodes, weights = jnp.asarray(_GL_NODES, dtype), jnp.asarray(_GL_WEIGHTS, dtype)
    y, x = rows.astype(dtype), cols.astype(dtype)
    top, bottom = y + 0.5, height - 0.5 - y
    left, right = x + 0.5, width - 0.5 - x
    triangles = [(top, left), (top, right), (bottom, left), (bottom, right),
                 (left, top), (left, bottom), (right, top), (right, bottom)]
    parts = []
    for a, b in triangles:  # a: perpendicular distance to a side (>= 0.5 px), b: along that side to a corner
        near = jnp.minimum(jnp.arctan2(b, a), math.pi / 4)
        parts.append((a, near, jnp.maximum(_safe_log(b / a), 0.0)))

    def node(k, total):  # one node of every rule per step: a loop, not unrolled, so the compile stays small
        f = (nodes[k] + 1) * 0.5
        for a, near, t_max in parts:
            total = total + (weights[k] * 0.5 * near)[..., None] * cdf(a * pixel_mm / jnp.cos(f * near))
            t = f * t_max
            dist = a * jnp.sqrt(1 + jnp.exp(2 * t))
            total = total + (weights[k] * 0.5 * t_max / (2 * jnp.cosh(t)))[..., None] * cdf(dist * pixel_mm)
        return total

    zero = jnp.zeros_like(cdf(pixel_mm))
    total = jax.lax.fori_loop(0, nodes.shape[0], node, zero)
    return total / (2 * math.pi)


@jax.custom_jvp
def weighted_mean(num: Array, den: Array) -> Array:
    """``num / den`` (a normalised sum of weights) whose derivative is ``(dnum - (num / den) dden) / den``: the
    quotient rule's form without the square of ``den``. A Burley pixel whose samples all land far across a depth step
    has a weight total of ~1e-27; ``num / den`` is fine there, but the derivative JAX writes, ``-num / den^2``,
    overflows float32 (den^2 = 1e-54 -> 0): the gradients in d and depth came out NaN."""
    return num / den


@weighted_mean.defjvp
def _weighted_mean_jvp(primals, tangents):
    num, den = primals
    d_num, d_den = tangents
    out = num / den
    return out, (d_num - out * d_den) / den


def padded_indices(mask: np.ndarray, capacity: int) -> np.ndarray:
    """Host-side compaction: the flat indices (int32, row-major) of ``mask``'s true pixels, padded to ``capacity``
    slots with ``mask.size`` (a pixel past the buffer: a gather clamps it, a scatter drops it). NumPy's flatnonzero
    takes ~0.1 ms at 640x360, XLA's nonzero (a prefix sum of reduce-windows and a scatter) ~1-2 ms."""
    where = np.flatnonzero(np.asarray(mask).reshape(-1))
    if where.size > capacity:
        raise ValueError(f"capacity {capacity} holds fewer slots than the {where.size} active pixels")
    idx = np.full(capacity, mask.size, np.int32)
    idx[:where.size] = where
    return idx


from .._errors import SamplingWarning as SamplingWarning  # noqa: E402  (the one definition is in _errors)


# an implied error (fraction of a hard edge's contrast) above which a configuration is called undersampled: the
# asymmetry goal of issue #18 for Burley's edge
SAMPLING_ERROR_LIMIT = 0.02
