"""The separable pass as a GPU runs it: whole frame, one fused loop over the taps, a gather at each pixel's own offset.

Jimenez's shader reads, for every pixel and tap, the irradiance at ``offset_mm * px_per_mm(pixel)`` along the pass:
the reach follows each pixel's depth and material exactly (no quantised levels, so their error is gone). The
arithmetic is the spec's (``_separable_spec``): a pixel a tap reads counts as far as it is valid and at the centre's
depth (``follow_surface``), the rest of the tap counts as the centre, and the part off the frame is dark
(``border="leaves"``) or the centre ("renormalise"); a kernel wider than the frame is cut there per pixel (decided on
the device by a ``lax.cond``: the cut's arithmetic runs only where some pixel needs it). Validity travels in the
depth plane itself (``z > 0``; ``_prepare`` zeroes the depth of pixels that take no part), so a tap fetches four
planes (R, G, B, z), not five.

``pass_result`` is written for any layout of pixels (its inputs explicit: per-pixel reach in px, follow-the-surface
scale, material row, position along the pass, a fetch function and the small tables of ``pass_tables``), so the XLA
gather here and the Pallas kernel (``_pallas``) compute one function and are checked against each other and against
an independent NumPy loop (``tests/test_oracle.py``).
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._scene import Buffers, Camera
from .._units import px_per_mm
from . import _separable_spec as spec
from ._common import _finish, _prepare, _work_dtype

# Taps unrolled per step of the tap loop: a step is one fused kernel over the frame, so this many taps share one
# read and write of the accumulator, while the compile time stays bounded (it grows with the step, not the taps).
TAPS_PER_STEP = 4


def pass_tables(w_table: Array, unit_offsets: Array, taps_per_step: int, cut: Array | None = None
                ) -> dict[str, Array]:
    """The small tables a whole-frame pass reads, flat (a Pallas kernel indexes them as refs, XLA as arrays), the taps
    padded to whole steps with taps of weight 0 at offset 0 and an empty cell: ``unit (n',)``, ``w (M 3 n')`` (row m,
    channel c, tap i at ``(3 m + c) n' + i``), ``wsum (M 3)``, and for the cut at the frame ``cell_lo``/``cell_hi
    (n',)`` (tap i's cell, unit offsets), ``knots (K + 1,)`` (``spec.cut_knots``) and ``cut (M 3 (K + 1))`` (the cut's
    table, ``spec.cut_table``: ``cut``, zeros where none is given)."""
    m, _, n = w_table.shape
    dtype = w_table.dtype
    steps = -(-n // taps_per_step)
    extra = steps * taps_per_step - n
    order = spec.tap_order(n)
    bounds = spec.cell_bounds(n)
    lo, hi = bounds[order], bounds[order + 1]  # tap i (pass order) is the order[i]-th from the left
    knots = spec.cut_knots(n)
    cut = jnp.zeros((m, 3, knots.shape[0]), dtype) if cut is None else cut.astype(dtype)
    return dict(unit=jnp.pad(unit_offsets, (0, extra)),
                w=jnp.pad(w_table, [(0, 0), (0, 0), (0, extra)]).reshape(-1),
                wsum=jnp.sum(w_table, axis=-1).reshape(-1),
                cell_lo=jnp.asarray(np.pad(lo, (0, extra)), dtype), cell_hi=jnp.asarray(np.pad(hi, (0, extra)), dtype),
                knots=jnp.asarray(knots, dtype), cut=cut.reshape(-1))


def pass_result(centre: Sequence[Array], z: Array, reach_px: Array, scale: Array, rows: Array, along: Array,
                fetch, tables, *, taps: int, length: int, origin_along: int, frame_length: int, leaves: bool,
                truncate: bool, one_row: bool, follow_surface: bool, interpolation: str,
                taps_per_step: int) -> list[Array]:
    """One pass at each pixel of a layout (a whole frame, a block of pixels), each at its own reach: the spec's taps
    (``_separable_spec``) with the weights of its material row, the kernel cut at the frame per pixel where
    ``truncate`` (where a pixel's kernel fits the frame, its own weights).

    ``centre``: the pixels' channels; ``z`` (0 where a pixel takes no part), ``reach_px``, ``scale`` (follow the
    surface), ``rows`` (material row), ``along`` (position along the pass in the buffer): per pixel; ``fetch(q)``:
    ``(channels, z)`` at position ``q`` (clipped into the buffer) on each pixel's line; ``tables``:
    ``pass_tables``' (arrays or Pallas refs). ``length``: the buffer's extent along the pass; ``origin_along``,
    ``frame_length``: its first pixel along the pass in the frame and the frame's extent (the border and the cut
    follow the frame)."""
    n_pad = tables["unit"].shape[0]
    limit = length + 1.0  # beyond the buffer by more than a pixel: every corner lands off it
    n = taps
    if truncate:
        cut = spec.truncation_scale(reach_px, spec.cell_edge(n), float(frame_length))
        fits = cut >= 1.0
        reach_px = reach_px * cut
    weight = lambda c, i: tables["w"][c * n_pad + i] if one_row else tables["w"][(rows * 3 + c) * n_pad + i]
    full_sum = [tables["wsum"][c] if one_row else tables["wsum"][rows * 3 + c] for c in range(3)]

    knots = tables["knots"].shape[0]

    def cumulative(x):  # the cut kernel's mass over [0, x] per channel at unit position x (``spec.cut_cumulative``)
        base = [c * knots if one_row else (rows * 3 + c) * knots for c in range(3)]
        return [spec.cut_cumulative(x, n, lambda j: tables["knots"][j], lambda j, b=b: tables["cut"][b + j])
                for b in base]

    if truncate:
        cut_sum = [2 * half for half in cumulative(cut * spec.cell_edge(n))]
        # leaves: the cut kernel's own mass; renormalise: scaled to the full kernel's total (``spec.renormalised``)
        gain = [1.0 if leaves else jnp.where(f > 0, s / jnp.where(f > 0, f, 1.0), 1.0)
                for s, f in zip(full_sum, cut_sum)]
        weight_sum = [jnp.where(fits, s, f * g) for s, f, g in zip(full_sum, cut_sum, gain)]
    else:
        weight_sum = full_sum

    def tap_weights(i):
        if not truncate:
            return [weight(c, i) for c in range(3)]
        mass = [hi - lo for hi, lo in zip(cumulative(cut * tables["cell_hi"][i]),
                                          cumulative(cut * tables["cell_lo"][i]))]
        return [jnp.where(fits, weight(c, i), mass[c] * gain[c]) for c in range(3)]

    def step(s, acc):
        kept_e, kept, left = acc
        for j in range(taps_per_step):
            i = s * taps_per_step + j
            off = spec.tap_offset(tables["unit"][i], reach_px, limit)
            fetched = []
            for shift, frac in spec.fetch_corners(off, interpolation):
                q = along + shift
                in_buffer = (q >= 0) & (q < length)
                q_frame = q + origin_along
                *e_q, z_q = fetch(jnp.clip(q, 0, length - 1))
                v_q = (in_buffer & (z_q > 0)).astype(z.dtype)  # a pixel that takes no part counts as the centre
                out_q = (~((q_frame >= 0) & (q_frame < frame_length))).astype(z.dtype) if leaves else None
                fetched.append((e_q, z_q, v_q, out_q, frac))
            a, k, o = spec.tap_sums(fetched, z, scale, follow_surface=follow_surface, planar=False)
            wts = tap_weights(i)
            kept_e = tuple(x + wt * y for x, wt, y in zip(kept_e, wts, a))
            kept = tuple(x + wt * k for x, wt in zip(kept, wts))
            if leaves:
                left = tuple(x + wt * o for x, wt in zip(left, wts))
        return kept_e, kept, left

    zero = tuple(jnp.zeros_like(z) for _ in range(3))
    init = (zero, zero, zero if leaves else ())
    steps = n_pad // taps_per_step
    kept_e, kept, left = step(0, init) if steps == 1 else jax.lax.fori_loop(0, steps, step, init)
    return [spec.pass_value(centre[c], weight_sum[c], kept_e[c], kept[c], left[c] if leaves else None)
            for c in range(3)]


def gather_pass(e: Float[Array, "3 H W"], z: Float[Array, "H W"], reach_px: Float[Array, "H W"],
                scale: Float[Array, "H W"], skip: Bool[Array, "H W"], rows: Int[Array, "H W"],
                w_table: Float[Array, "M 3 n"], unit_offsets: Float[Array, " n"],
                cut_table: Float[Array, "M 3 K"] | None = None, *, axis: int, follow_surface: bool,
                interpolation: str, border: str = "renormalise", origin_along: int = 0,
                frame_length: int | None = None, taps_per_step: int = TAPS_PER_STEP) -> Float[Array, "3 H W"]:
    """One 1D pass of planar irradiance ``e`` along ``axis`` (2 horizontal, 1 vertical), XLA formulation.

    ``z``: depth in scene units, 0 where the pixel takes no part. ``reach_px``: the kernel's reach at each pixel, in
    px (a tap at unit offset ``u`` lands ``u * reach_px`` px away, clipped just beyond the buffer). ``scale``: the
    depth difference (scene units) times ``scale`` is the fraction a fetched pixel stops counting by
    (``mm_per_unit / reach_mm``). ``rows``: each pixel's row of ``w_table (M, 3, n)`` (tap weights per channel).
    ``skip`` pixels keep their value. ``interpolation``: "bilinear" (two pixels, weights 1 - f and f) or "nearest".
    ``border``, ``origin_along``, ``frame_length``: as ``pass_result``. A kernel reaching past the frame is cut
    there per pixel (decided on the device: the cut's arithmetic runs only where some pixel needs it), re-integrated
    from ``cut_table (M, 3, K + 1)`` (``spec.cut_table``); ``None`` where the caller knows that no kernel reaches
    past the frame (no cut is made)."""
    if axis not in (1, 2):
        raise ValueError(f"axis must be 1 (vertical) or 2 (horizontal), got {axis!r}")
    _, h, w = e.shape
    length = w if axis == 2 else h
    frame_length = length if frame_length is None else int(frame_length)
    along = jax.lax.broadcasted_iota(jnp.int32, (h, w), axis - 1)  # each pixel's position along the pass
    tables = pass_tables(w_table, unit_offsets, taps_per_step, cut_table)
    # one gather per corner fetches the four planes of a pixel (flat, row-major: q is a position on the line)
    packed = jnp.stack([e[0], e[1], e[2], z], axis=-1).reshape(h * w, 4)
    line = jax.lax.broadcasted_iota(jnp.int32, (h, w), 0) * w if axis == 2 else \
        jax.lax.broadcasted_iota(jnp.int32, (h, w), 1)
    stride = 1 if axis == 2 else w
    fetch = lambda q: list(jnp.moveaxis(jnp.take(packed, line + q * stride, axis=0), -1, 0))
    kw = dict(taps=unit_offsets.shape[0], length=length, origin_along=int(origin_along),
              frame_length=frame_length, leaves=border == "leaves", one_row=w_table.shape[0] == 1,
              follow_surface=follow_surface, interpolation=interpolation)
    # the cut (rare: a kernel wider than the frame) one tap per loop step: its arithmetic per tap is larger, and a
    # smaller unrolled body keeps the compile time of the branch that seldom runs small
    run = lambda truncate: tuple(pass_result(list(e), z, reach_px, scale, rows, along, fetch, tables,
                                             truncate=truncate, taps_per_step=1 if truncate else taps_per_step, **kw))
    if cut_table is None:
        out = run(False)
    else:
        out = jax.lax.cond(needs_cut(reach_px, skip, unit_offsets.shape[0], frame_length), lambda: run(True),
                           lambda: run(False))
    return jnp.where(skip[None], e, jnp.stack(out))


def needs_cut(reach_px: Array, skip: Array, taps: int, frame_length: int) -> Array:
    """Whether some pixel's kernel reaches past the frame along the pass (its outer cells end beyond the extent), on
    the device: what decides a whole-frame pass's ``lax.cond`` between the cut and the plain taps."""
    return jnp.any(jnp.where(skip, 0.0, reach_px) * spec.cell_edge(taps) > frame_length)


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
    cut_table: Array  # (M, 3, K + 1): the cut at the frame's (``spec.cut_table``)


def pass_inputs(buffers: Buffers, material, camera: Camera, prep, taps: int, min_footprint_px: float,
                kernel_groups: tuple[int, ...] | None, dtype, frame_shape: tuple[int, int]) -> PassInputs:
    """Per-pixel reach (material row's kernel reach times px per mm at the pixel's depth), the follow-the-surface
    scale and the skip flag (no surface, or a footprint below ``min_footprint_px``), as ``separable`` defines them,
    and the table of the kernels' cut at the frame (``frame_shape``): built on the device only where some pixel's
    kernel reaches past the frame along a pass (zeros otherwise: no pass reads it then)."""
    rows, kernel_material = prep.rows, spec.distinct_kernels(material, kernel_groups)
    if kernel_groups is not None:  # materials with one kernel share its table row
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
    w_table = jnp.moveaxis(weights, -1, 1)
    knots = spec.cut_knots(taps)
    build = lambda: spec.material_cut_table(kernel_material, taps, dtype, w_table)
    cut = needs_cut(reach_px, ~active, taps, min(frame_shape))  # the shorter extent: either pass
    cut_table = jax.lax.cond(cut, build, lambda: jnp.zeros(w_table.shape[:2] + knots.shape, dtype))
    return PassInputs(e=jnp.moveaxis(prep.irradiance, -1, 0), z=prep.depth, reach_px=reach_px,
                      scale=mm_per_unit * inv_reach_mm, skip=~active, rows=rows, w_table=w_table,
                      unit_offsets=jnp.asarray(spec.pass_unit_offsets(taps), dtype), cut_table=cut_table)
