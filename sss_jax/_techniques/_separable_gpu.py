"""The separable pass as a GPU runs it: whole frame, one fused loop over the taps, a gather at each pixel's own offset.

Jimenez's shader reads, for every pixel and tap, the irradiance at ``offset_mm * px_per_mm(pixel)`` along the pass:
the reach follows each pixel's depth and material exactly (no quantised levels, so their error is gone). A pixel a
tap reads counts as far as it is valid and at the centre's depth (``follow_surface``: full at equal depth, none at
the kernel's reach); the rest of the tap, and taps landing off the frame, count as the centre colour. Validity
travels in the depth plane itself (``z > 0``; ``_prepare`` zeroes the depth of pixels that take no part), so a tap
fetches four planes (R, G, B, z), not five.

``gather_pass`` is written with its inputs explicit (per-pixel reach in px, follow-the-surface scale, material row,
the unit tap pattern and the weight table), so the XLA formulation here and the Pallas kernel (``_pallas``) compute
one function and can be checked against each other and against a pixel-by-pixel loop.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._kernels import centre_first, unit_tap_offsets
from .._scene import Buffers, Camera
from .._units import px_per_mm
from ._common import _finish, _prepare, _work_dtype

# Taps unrolled per step of the tap loop: a step is one fused kernel over the frame, so this many taps share one
# read and write of the accumulator, while the compile time stays bounded (it grows with the step, not the taps).
TAPS_PER_STEP = 4


def tap_term(off: Array, along: Array, length: int, fetch, e: Sequence[Array], z: Array, scale: Array, *,
             follow_surface: bool, interpolation: str) -> list[Array]:
    """What one tap adds per channel, before its weight: ``sum_q frac_q keep_q (e_q - e)`` over the pixels q it reads.

    ``off``: the tap's offset along the pass at each pixel (px, already clipped just beyond the frame); ``along``:
    each pixel's position along the pass; ``fetch(q)``: the channels and depth at position ``q`` (clipped into the
    frame) on each pixel's line. Layout-free (a frame or a block of pixels), so the XLA pass and the Pallas kernel
    share it."""
    if interpolation == "nearest":
        corners = [(jnp.round(off), None)]
    else:
        x0 = jnp.floor(off)
        f = off - x0
        corners = [(x0, 1 - f), (x0 + 1, f)]
    term = [0.0, 0.0, 0.0]
    for shift, frac in corners:
        q = along + shift.astype(jnp.int32)
        inside = (q >= 0) & (q < length)
        *ev, zv = fetch(jnp.clip(q, 0, length - 1))
        valid = inside & (zv > 0)  # off the frame, or a pixel that takes no part: counts as the centre
        keep = jnp.maximum(1 - jnp.abs(zv - z) * scale, 0.0) if follow_surface else 1.0
        keep = jnp.where(valid, keep, 0.0)
        keep = keep if frac is None else frac * keep
        term = [t + keep * (a - b) for t, a, b in zip(term, ev, e)]
    return term


def gather_pass(e: Float[Array, "3 H W"], z: Float[Array, "H W"], reach_px: Float[Array, "H W"],
                scale: Float[Array, "H W"], skip: Bool[Array, "H W"], rows: Int[Array, "H W"],
                w_table: Float[Array, "M 3 n"], unit_offsets: Float[Array, " n"], *, axis: int,
                follow_surface: bool, interpolation: str, taps_per_step: int = TAPS_PER_STEP) -> Float[Array, "3 H W"]:
    """One 1D pass of planar irradiance ``e`` along ``axis`` (2 horizontal, 1 vertical), XLA formulation.

    ``z``: depth in scene units, 0 where the pixel takes no part. ``reach_px``: the kernel's reach at each pixel, in
    px (a tap at unit offset ``u`` lands ``u * reach_px`` px away, clipped just beyond the frame). ``scale``: the
    depth difference (scene units) times ``scale`` is the fraction a fetched pixel stops counting by
    (``mm_per_unit / reach_mm``). ``rows``: each pixel's row of ``w_table (M, 3, n)`` (tap weights per channel).
    ``skip`` pixels keep their value. ``interpolation``: "bilinear" (two pixels, weights 1 - f and f) or "nearest"."""
    if axis not in (1, 2):
        raise ValueError(f"axis must be 1 (vertical) or 2 (horizontal), got {axis!r}")
    _, h, w = e.shape
    length = w if axis == 2 else h
    along = jax.lax.broadcasted_iota(jnp.int32, (h, w), axis - 1)  # each pixel's position along the pass
    limit = length + 1.0  # beyond the frame by more than a pixel: every corner lands off it
    n = unit_offsets.shape[0]
    steps = -(-n // taps_per_step)
    extra = steps * taps_per_step - n  # padding taps: weight 0 at offset 0
    unit_offsets = jnp.pad(unit_offsets, (0, extra))
    w_table = jnp.pad(w_table, [(0, 0), (0, 0), (0, extra)])
    # one gather per corner fetches the four planes of a pixel (flat, row-major: q is a position on the line)
    packed = jnp.stack([e[0], e[1], e[2], z], axis=-1).reshape(h * w, 4)
    line = jax.lax.broadcasted_iota(jnp.int32, (h, w), 0) * w if axis == 2 else \
        jax.lax.broadcasted_iota(jnp.int32, (h, w), 1)
    stride = 1 if axis == 2 else w
    fetch = lambda q: list(jnp.moveaxis(jnp.take(packed, line + q * stride, axis=0), -1, 0))
    centre = (e[0], e[1], e[2])
    weight_sum = jnp.sum(w_table, axis=-1)  # (M, 3)
    if w_table.shape[0] == 1:  # one material: a weight per channel and tap, no per-pixel lookup
        tap_weight = lambda i, c: w_table[0, c, i]
        weight_sum = [weight_sum[0, c] for c in range(3)]
    else:
        tap_weight = lambda i, c: w_table[:, c, i][rows]
        weight_sum = [weight_sum[:, c][rows] for c in range(3)]

    def step(s, acc):
        for j in range(taps_per_step):
            i = s * taps_per_step + j
            off = jnp.clip(unit_offsets[i] * reach_px, -limit, limit)
            term = tap_term(off, along, length, fetch, centre, z, scale, follow_surface=follow_surface,
                            interpolation=interpolation)
            acc = tuple(a + tap_weight(i, c) * t for c, (a, t) in enumerate(zip(acc, term)))
        return acc

    out = tuple(centre[c] * weight_sum[c] for c in range(3))
    out = step(0, out) if steps == 1 else jax.lax.fori_loop(0, steps, step, out)
    return jnp.where(skip[None], e, jnp.stack(out))


class PassInputs(eqx.Module):
    """What both passes of a frame share: the prepared frame and each pixel's reach, scale, row and skip flag."""

    e: Array  # (3, H, W) irradiance to scatter, 0 where invalid
    z: Array  # (H, W) depth, 0 where invalid
    reach_px: Array
    scale: Array
    skip: Array
    rows: Array
    w_table: Array  # (M, 3, n)
    unit_offsets: Array  # (n,)


def pass_inputs(buffers: Buffers, material, camera: Camera, prep, taps: int, min_footprint_px: float,
                kernel_groups: tuple[int, ...] | None, dtype) -> PassInputs:
    """Per-pixel reach (material row's kernel reach times px per mm at the pixel's depth), the follow-the-surface
    scale and the skip flag (no surface, or a footprint below ``min_footprint_px``), as ``separable`` defines them."""
    rows, kernel_material = prep.rows, material
    if kernel_groups is not None:  # materials with one kernel share its table row
        first = np.asarray([kernel_groups.index(g) for g in range(max(kernel_groups) + 1)])
        kernel_material = jax.tree.map(lambda a: a[first], material)
        rows = jnp.asarray(kernel_groups, jnp.int32)[rows]
    kernels = kernel_material.separable_kernels(taps, dtype)
    offsets, weights = kernels.offsets_mm.astype(dtype), kernels.weights.astype(dtype)  # (K, n) mm, (K, n, 3)
    mm_per_unit = camera.mm_per_unit.astype(dtype)
    ppm = px_per_mm(prep.depth, focal_px=camera.focal_px.astype(dtype), mm_per_unit=mm_per_unit)
    ppm = jnp.where(prep.valid, ppm, 0.0)
    reach_mm = jnp.max(jnp.abs(offsets), axis=-1)[rows]  # every kernel is its reach times one tap pattern
    reach_px = reach_mm * ppm
    ok_reach = reach_mm > 0
    inv_reach_mm = jnp.where(ok_reach, 1.0 / jnp.where(ok_reach, reach_mm, 1.0), 0.0)
    active = prep.valid & (reach_px >= min_footprint_px) & (reach_px > 0)
    return PassInputs(e=jnp.moveaxis(prep.irradiance, -1, 0), z=prep.depth, reach_px=reach_px,
                      scale=mm_per_unit * inv_reach_mm, skip=~active, rows=rows,
                      w_table=jnp.moveaxis(weights, -1, 1),
                      unit_offsets=jnp.asarray(unit_tap_offsets(taps)[centre_first(taps)], dtype))
