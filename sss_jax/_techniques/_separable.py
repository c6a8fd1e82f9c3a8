"""Separable subsurface scattering (Jimenez et al. 2015): a horizontal then a vertical 1D pass, depth-aware."""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import check_host_count
from .._errors import TilePlacementError
from .._kernels import _check_taps
from .._materials import (
    AbstractMaterial,
    BurleyMaterial,
    ProfileMaterial,
    TwoGaussianMaterial,
)
from .._scene import Buffers, Camera, surface_mask
from .._units import px_per_mm
from ._common import (
    MIN_FOOTPRINT_PX,
    SAMPLING_ERROR_LIMIT,
    SamplingWarning,
    _check_albedo_mode,
    _check_border,
    _finish,
    _is_concrete,
    _prepare,
    _safe_log,
    _work_dtype,
    check_one_image,
)
from . import _separable_spec as spec
from ._dispatch import check_tile, resolve_impl
from ._whole_frame import separable_gpu_impl

# Pixel-scale levels of the separable pass: each level is one shifted-slice pass at a constant reach; a pixel
# blends the two levels that bracket its own reach (in log scale), so the result stays continuous in d and depth.
# Two levels: on the demo scene (640x360, 25 taps) as accurate against the reference as four (rel. L2 0.0161 against
# 0.0164; the levels' own error is ~0.0015 next to the technique's ~0.016) and ~1.4-2x faster on a CPU.
SCALE_LEVELS = 2


def _separable_level(fetch: Callable[[Array], tuple[Array, Array]], z: Array, reach_px: Array,
                     tap_weight: Callable[[Array | int], Array], unit_offsets: Array, taps_per_chunk: int,
                     limit: float, follow_surface: bool, interpolation: str,
                     skip_centre: bool = False) -> tuple[Array, Array]:
    """One 1D pass at one constant reach ``reach_px`` (a scalar) over a block of pixels: the weighted sums ``(A, K)``
    of ``_separable_spec.tap_sums`` (planar ``(3, rows, cols)``), for ``_separable_spec.pass_value``.
    ``fetch(start)`` returns the padded planes (irradiance times validity, and depth, ``spec.FAR`` where a pixel takes
    no part or off the buffer) shifted by ``start`` pixels along the pass, so every tap is a constant shift (with
    ``follow_surface`` the depths ``z`` and the fetched come multiplied by the material's scale); at a
    constant reach each corner's fraction is one number per tap, folded into the tap's weight. The taps are unrolled
    ``taps_per_chunk`` at a time into one expression, which XLA fuses into one loop over the block (each pixel reads
    a chunk's taps and adds them to its sums at once); a loop runs the chunks, so the compile time and the fusions'
    size stay bounded as the taps grow. ``unit_offsets`` has a whole number of chunks (padding taps have weight 0).
    No division and no transcendental per tap, so nothing stops XLA from fusing a chunk whole. ``skip_centre``: tap 0
    is the centre (unit offset 0), which adds nothing (``_separable_spec``, above ``pass_value``): not fetched."""
    def chunk(c, acc):
        kept_e, kept = acc
        for j in range(taps_per_chunk):
            i = c * taps_per_chunk + j
            if skip_centre and isinstance(c, int) and c == 0 and j == 0:  # the centre: adds nothing
                continue
            # offsets beyond the image land in the padding: nothing valid there
            off = spec.tap_offset(unit_offsets[i], reach_px, limit)
            w_i = tap_weight(i)
            for start, frac in spec.fetch_corners(off, interpolation):
                # the corner's fraction is one number at a constant reach: it weighs the tap, not each pixel
                kept_e, kept = _add_fetch((kept_e, kept), *fetch(start), z, w_i if frac is None else w_i * frac,
                                          follow_surface=follow_surface)
        return kept_e, kept

    zero = jnp.zeros((3,) + z.shape, z.dtype)
    chunks = unit_offsets.shape[0] // taps_per_chunk
    first = chunk(0, (zero, zero))  # on its own: it holds the centre
    return first if chunks == 1 else jax.lax.fori_loop(1, chunks, chunk, first)


@functools.partial(jax.jit, static_argnames=("follow_surface",))
def _add_fetch(sums: tuple[Array, Array], ev: Array, zv: Array, z: Array, weight: Array, *, follow_surface: bool
               ) -> tuple[Array, Array]:
    """``_separable_level``'s sums ``(A, K)`` with one fetch of a tap added (``spec.tap_sums``, planar, weighed by
    ``weight``, the tap's weight times the corner's fraction). A function of its own, jitted: every tap's fetch is
    traced once (the unrolled taps are then one cached call each, which XLA inlines: the same program, traced and
    lowered faster)."""
    a, k, _ = spec.tap_sums([(ev, zv, None, None, None)], z, None, follow_surface=follow_surface, planar=True)
    return sums[0] + weight * a, sums[1] + weight * k[None]


def _leaving(outside_pad: Array, pad: int, length: int, unit_offsets: Array, reach_px: Array, w_level: Array,
             interpolation: str, limit: float) -> Array:
    """``O`` of ``_separable_spec.tap_sums`` at one constant reach, tap weights ``w_level (3, n)``, for every
    position along the pass, per channel ``(3, length)``: the weighted share of the taps landing off the frame
    (``border="leaves"``). It depends on the position along the pass only, so it is computed once per level on a
    line, not per pixel."""
    off = spec.tap_offset(unit_offsets, reach_px, limit)  # (n,)
    position = jnp.arange(length)[None, :]
    total = 0.0
    for start, frac in spec.fetch_corners(off, interpolation):
        o = outside_pad[pad + start[:, None] + position]  # (n, length)
        if frac is not None:
            o = frac[:, None] * o
        total = total + w_level @ o
    return total


frame_truncation = spec.frame_truncation  # the spec's (the host check and the tests read it here too)


def tap_chunks(taps: int, *, derivative: bool = False) -> tuple[int, int]:
    """(chunks, taps per chunk) of a separable pass, the taps spread evenly over the chunks: one chunk up to
    ``_TAPS_PER_FUSION`` taps; beyond, chunks of at most ``_TAPS_PER_LOOP_CHUNK`` taps, never fewer than three. The
    first chunk runs on its own and a loop runs the rest (``_separable_level``): with two chunks that loop would run
    once, and XLA removes a loop of one iteration and fuses both chunks' taps into one expression again, the case
    the chunks are there to avoid. ``derivative``: the pass as its derivatives evaluate it (``_separable_passes``),
    in chunks of at most ``_TAPS_PER_DERIVATIVE_CHUNK`` taps."""
    if derivative:
        chunks = max(3, -(-taps // _TAPS_PER_DERIVATIVE_CHUNK))
        return chunks, -(-taps // chunks)
    if taps <= _TAPS_PER_FUSION:
        return 1, taps
    chunks = max(3, -(-taps // _TAPS_PER_LOOP_CHUNK))
    return chunks, -(-taps // chunks)


# Taps fused into one loop over a band. Unrolling every tap of a wide kernel into one expression makes XLA's CPU
# fusion fall apart past ~60 taps (2026-12-03, 256x256, the demo frame, one chunk: 49 taps 6.1 ms, 57 taps 7.2 ms,
# 65 taps 55 ms, against 33 taps 3.8 ms). Until this round 65 taps ran as two chunks of 33, which XLA fused back into
# one (above): 64 ms at 256x256, 304 ms at 640x640 (33 taps: 36 ms). As chunks of at most 17 taps in a loop: 65 taps
# 9.8-11.8 ms at 256x256 (compiled in 3.6-3.9 s, against 4.9-5.4 s), 30 ms at 360x640 (58 ms); 97 taps 15.6 ms,
# 129 taps 20.5 ms (chunks of 33: 18.5 and 22.3 ms, compiled in 6.3-6.4 s against 3.6-4.3 s). Up to 49 taps one
# chunk is the fastest (35 / 41 / 49 taps: 5.6 / 6.0 / 6.1 ms at 256x256, against 7.3 / 7.7 / 8.7-11.6 ms in three
# chunks of 12-17; 49 taps at 360x640 23 ms against 29, at 1080x1920 191 ms against 202).
_TAPS_PER_FUSION = 49
_TAPS_PER_LOOP_CHUNK = 17
# Taps per chunk where the pass is differentiated (``_separable_passes``' JVP rule). A chunk's taps unrolled are the
# program XLA compiles for the forward pass, its tangent and their transpose: the derivative's compile time grew
# with the taps per chunk (2026-12-07, 2-core CPU, an 8x8 frame, gradients in d, the albedo and the irradiance at the
# suite's XLA flags: 25 taps in one chunk 35-40 s, in chunks of 9 31 s, of 5 16 s, of 3 9.7-12.0 s, of 2 9.5 s, of 1
# 7.1 s; 9 taps 12.7 s, 5 taps 8.8 s), and at the default flags a jitted gradient at 256x256, 25 taps, compiled in
# 52.7 s and ran in 1.29 s in one chunk against 19.9-24.8 s and 1.03-1.34 s in chunks of 3 (24.5 s and 0.99 s in
# chunks of 5; 14.3 s and 1.08 s one tap at a time, measured beside 24.8 s and 1.34 s for chunks of 3).
_TAPS_PER_DERIVATIVE_CHUNK = 1


def _band_rows(height: int, width: int) -> int:
    """Rows per band of a pass: at least ``_MIN_BANDS`` bands (finer cost-following), and few enough pixels per band
    that the rows a tap reads stay in the L2 cache (1920x1080: 18 rows, ~9% faster than 68), at least 8 rows each."""
    return max(8, min(-(-height // _MIN_BANDS), -(-_BAND_PIXELS // width)))


_MIN_BANDS = 16
_BAND_PIXELS = 1 << 15
BLOCK_COLS = 128  # columns per block of a band: blocks without SSS pixels compute nothing


def _block_needs(used: Callable[[int], Array], pairs: int, shape: tuple[int, int], rows_per_band: int,
                 cols: int) -> Array:
    """``(blocks, P)``: whether any pixel of each block (bands of ``rows_per_band`` rows cut into ``cols`` columns, the
    last band and column block ending at the frame's edge) is set in mask ``used(p) (H, W)`` of pair ``p``; blocks
    numbered band by band. A block that overlaps the one before (the last, where the size is no multiple of the
    block) also answers for the grid block it overlaps: a superset, which computes nothing wrong (a pair without
    pixels adds zero). Up to 32 pairs travel as the bits of one plane, reduced with OR over each block (one pass over
    the frame, not one per pair)."""
    h, w = shape
    bands, col_blocks = -(-h // rows_per_band), -(-w // cols)
    words = [list(range(p, min(p + 32, pairs))) for p in range(0, pairs, 32)]
    grids = []
    for word in words:
        bits = sum(used(p).astype(jnp.uint32) << np.uint32(p - word[0]) for p in word)
        grid = jnp.pad(bits, [(0, bands * rows_per_band - h), (0, col_blocks * cols - w)])
        grids.append(jax.lax.reduce(grid.reshape(bands, rows_per_band, col_blocks, cols), np.uint32(0),
                                    jax.lax.bitwise_or, (1, 3)))  # (bands, col_blocks)
    grid = jnp.stack(grids)
    if h % rows_per_band and bands > 1:
        grid = grid.at[:, -1].set(grid[:, -1] | grid[:, -2])
    if w % cols and col_blocks > 1:
        grid = grid.at[:, :, -1].set(grid[:, :, -1] | grid[:, :, -2])
    flat = grid.reshape(len(words), bands * col_blocks)
    return jnp.concatenate([(flat[i][:, None] >> np.arange(len(word), dtype=np.uint32)[None]) & 1
                            for i, word in enumerate(words)], axis=1) > 0


def _separable_pass(e: Array, z: Array, valid: Array, level_weights: Array, level_reach_px: Array, skip: Array,
                    onehot: Array | None, w_table: Array, inv_reach_mm: Array | float, unit_offsets: Array,
                    mm_per_unit: Array, follow_surface: bool, interpolation: str,
                    rows_per_band: int | None = None, axis: int = 2, border: str = "leaves",
                    origin_along: int = 0, frame_length: int | None = None, block_cols: int | None = None,
                    skip_centre: bool = False, cut_table: Callable[[], Array] | Array | None = None,
                    derivative: bool = False) -> Array:
    """One 1D pass of planar ``e (3, H, W)`` along ``axis``: 2 horizontal, 1 vertical (no transposes: both read
    whole rows). Each material row's levels (``level_reach_px (M, L)``, or ``(L,)`` shared) are shifted-slice passes
    blended per pixel by ``level_weights (L, H, W)`` and ``onehot (M, H, W)`` (the pixel's row; ``None`` for one
    material); a (row, level) pair runs with its own tap weights, one number per tap and channel (``w_table (M, 3,
    n)``); ``skip`` pixels keep their own value. ``inv_reach_mm (M,)``: one over each row's kernel reach in mm (with
    ``mm_per_unit``, the depth difference at which a fetched pixel stops counting). ``cut_table``: the cut at the
    frame's ``(M, 3, K + 1)`` (``spec.cut_table``), or a function building it (called only where a level is cut:
    traced parameters build it inside the pass), or ``None`` where the caller knows that no level is cut.

    The frame is cut into blocks (bands of rows, each cut into ``block_cols`` columns; independent in either pass: a
    block reads its taps from the planes padded by one block along the pass) and each block computes only the pairs
    its own pixels use (a block without SSS pixels computes none): the cost follows the scene's coverage and depth
    range. A loop writes each block in place into the output (the last band and column block end at the frame's
    last row and column, overlapping the one before where the size is no multiple of the block: same values): no
    reassembly copy. A tile of a larger frame passes its first pixel along the pass in the frame
    (``origin_along``) and the frame's extent along it (``frame_length``): the border and the cut of wide kernels
    follow the frame. ``skip_centre``: the first unit offset is the centre's (0), whose tap adds nothing.
    ``derivative``: the taps in the chunks derivatives take (``tap_chunks``)."""
    if axis not in (1, 2):
        raise ValueError(f"axis must be 1 (vertical) or 2 (horizontal), got {axis!r}")
    _, h, w = e.shape
    rows_per_band = min(rows_per_band or _band_rows(h, w), h)
    cols = min(block_cols or BLOCK_COLS, w)
    bands = -(-h // rows_per_band)  # the last band ends at the last row (it may overlap the one before: same values)
    col_blocks = -(-w // cols)
    along = w if axis == 2 else h
    # a block's window along the pass is clamped to just outside the frame where it lies wholly outside (it reads
    # the padding: nothing takes part there), so the padding is one block wide, whatever the reach
    block_len = cols if axis == 2 else rows_per_band
    pad = block_len
    v = valid.astype(e.dtype)
    pad_width = [(0, 0), (pad, pad)] if axis == 2 else [(pad, pad), (0, 0)]
    # validity travels in the depth (``spec.FAR`` where a pixel takes no part, and in the padding)
    count = w_table.shape[0]
    # the follow-the-surface scale is a material's (mm per unit over its kernel's reach): with it, each material's
    # depth planes are scaled once, and a fetched pixel's weight is max(1 - |z_q - z|, 0) on them
    scale = mm_per_unit * jnp.broadcast_to(inv_reach_mm, (count,))
    z_in = jnp.where(valid, z, spec.FAR)
    if follow_surface:
        z_in = z_in[None] * scale[:, None, None]  # (M, H, W): FAR stays beyond any reach (inf is as good)
    ev_pad = jnp.pad(e * v[None], [(0, 0)] + pad_width)
    z_pad = jnp.pad(z_in, [(0, 0)] * (z_in.ndim - 2) + pad_width, constant_values=spec.FAR)
    frame_length = along if frame_length is None else int(frame_length)
    leaves = border == "leaves"
    planes = {"e": e, "z": z, "lw": level_weights, "skip": skip}
    if onehot is not None:
        planes["onehot"] = onehot
    level_reach_px = jnp.broadcast_to(level_reach_px, (count, level_weights.shape[0]))  # (M, L): each row's levels
    levels = level_reach_px.shape[1]

    # kernels reaching past the frame are cut at its extent (the rest leaves), their taps spread over it
    level_scale = spec.truncation_scale(level_reach_px, spec.cell_edge(unit_offsets.shape[0]), float(frame_length))
    uncut = jnp.broadcast_to(w_table[:, None], (count, levels) + w_table.shape[1:])  # (M, L, 3, n)
    if cut_table is None:
        w_levels = uncut
    else:
        def cut_levels():  # the table built (or read) only where a level is cut: a close-up
            table = cut_table() if callable(cut_table) else cut_table
            cut = lambda r, w_m, t_m: spec.frame_truncation(unit_offsets, w_m[None], r, float(frame_length),
                                                            t_m[None])[1][:, 0]
            return jax.vmap(cut)(level_reach_px, w_table, table.astype(w_table.dtype))

        w_levels = jax.lax.cond(jnp.any(level_scale < 1.0), cut_levels, lambda: uncut)
    if not leaves:  # the cut kernel renormalised: its part beyond the frame counts as the part inside
        w_levels = spec.renormalised(w_levels, jnp.sum(w_table, axis=-1, keepdims=True)[:, None])
    chunks, per_chunk = tap_chunks(unit_offsets.shape[0], derivative=derivative)
    extra_taps = chunks * per_chunk - unit_offsets.shape[0]  # padding taps: weight 0 at offset 0 (the centre: adds 0)
    unit_offsets = jnp.pad(unit_offsets, (0, extra_taps))
    w_levels = jnp.pad(w_levels, [(0, 0), (0, 0), (0, 0), (0, extra_taps)])
    weight_sums = jnp.sum(w_levels, axis=-1)  # (M, L, 3)
    limit = along + 1.0  # an offset clipped here lands off the buffer from every pixel
    reach_levels = level_reach_px * level_scale
    if leaves:  # O of the spec per material row, level, channel and position along the pass: (M, L, 3, along)
        line_pad = along + 2  # every clipped offset lands inside it
        position = np.arange(-line_pad, along + line_pad) + int(origin_along)  # in the frame
        outside_pad = jnp.asarray((position < 0) | (position >= frame_length), e.dtype)
        line_share = lambda r, wl: _leaving(outside_pad, line_pad, along, unit_offsets, r, wl, interpolation, limit)
        leaving = jax.vmap(jax.vmap(line_share))(reach_levels, w_levels)

    # which (material row, level) pairs each block needs, decided for all blocks at once: the loop then skips a
    # block, and a pair within it, on one number (no per-block reductions, slices or writes where nothing runs)
    used = ((lambda p: level_weights[p] > 0) if onehot is None
            else (lambda p: (level_weights[p % levels] > 0) & (onehot[p // levels] > 0)))
    needs = _block_needs(used, count * levels, (h, w), rows_per_band, cols)  # (blocks, M L)
    block_needed = jnp.any(needs, axis=1)

    def block(k, out):
        row0 = jnp.minimum((k // col_blocks) * rows_per_band, h - rows_per_band).astype(jnp.int32)
        col0 = jnp.minimum((k % col_blocks) * cols, w - cols).astype(jnp.int32)
        o = jnp.zeros((), jnp.int32)  # index arguments of one type (int64 under x64 otherwise)

        def work():
            b = {name: jax.lax.dynamic_slice(a, (o,) * (a.ndim - 2) + (row0, col0),
                                             a.shape[:-2] + (rows_per_band, cols)) for name, a in planes.items()}

            def fetch(start, m):
                at = jnp.clip((col0 if axis == 2 else row0) + start, -block_len, along) + pad  # in the padded planes
                row, col = (row0, at) if axis == 2 else (at, col0)
                zq = (jax.lax.dynamic_slice(z_pad, (m, row, col), (1, rows_per_band, cols))[0] if follow_surface
                      else jax.lax.dynamic_slice(z_pad, (row, col), (rows_per_band, cols)))
                return jax.lax.dynamic_slice(ev_pad, (o, row, col), (3, rows_per_band, cols)), zq

            def level(p, acc):  # one (material row, level) pair: its reach and tap weights are one number each
                m, j = p // levels, p % levels

                def run():
                    blend = b["lw"][j] if onehot is None else b["lw"][j] * b["onehot"][m]
                    w_p = w_levels[m, j]
                    tap_weight = lambda i: w_p[:, i][:, None, None]
                    zc = b["z"] * scale[m] if follow_surface else b["z"]
                    m_index = jnp.asarray(m, jnp.int32)
                    kept_e, kept = _separable_level(lambda start: fetch(start, m_index), zc,
                                                    reach_levels[m, j], tap_weight, unit_offsets, per_chunk, limit,
                                                    follow_surface, interpolation, skip_centre)
                    left = None
                    if leaves:  # the line's share leaving: (3, 1, cols) or (3, rows, 1)
                        start = col0 if axis == 2 else row0
                        size = cols if axis == 2 else rows_per_band
                        line = jax.lax.dynamic_slice_in_dim(leaving[m, j], start, size, axis=1)
                        left = line[:, None, :] if axis == 2 else line[:, :, None]
                    return acc + blend[None] * spec.pass_value(b["e"], weight_sums[m, j][:, None, None], kept_e, kept,
                                                               left)

                return jax.lax.cond(needs[k, p], run, lambda: acc)

            # a loop, not unrolled: the compile time does not grow with the number of materials and levels
            result = jax.lax.fori_loop(0, count * levels, level, jnp.zeros_like(b["e"]))
            result = jnp.where(b["skip"][None], b["e"], result)
            return jax.lax.dynamic_update_slice(out, result, (o, row0, col0))  # in place

        return jax.lax.cond(block_needed[k], work, lambda: out)

    return jax.lax.fori_loop(0, bands * col_blocks, block, e)


def check_separable_counts(taps, scale_levels, min_footprint_px) -> None:
    """``separable``'s taps (odd, positive), reach levels (a positive integer) and footprint floor (>= 0): what the
    function checks before it runs and a ``Separable`` object when it is made."""
    _check_taps(taps)
    check_host_count(scale_levels, "scale_levels")
    if not (float(min_footprint_px) >= 0):
        raise ValueError(f"min_footprint_px must be >= 0, got {min_footprint_px!r}")


@functools.partial(jax.jit, static_argnames=("taps", "albedo_mode", "follow_surface", "interpolation", "scale_levels",
                                             "min_footprint_px", "kernel_groups", "border", "origin", "frame_shape"))
def _separable_impl(buffers: Buffers, material, camera: Camera, taps: int, albedo_mode: str, follow_surface: bool,
                    interpolation: str, scale_levels: int, min_footprint_px: float,
                    kernel_groups: tuple[int, ...] | None = None, border: str = "leaves",
                    origin: tuple[int, int] = (0, 0), frame_shape: tuple[int, int] | None = None,
                    kernels: tuple[Array, Array, Array | None] | None = None) -> Array:
    options = _PassOptions(taps, albedo_mode, follow_surface, interpolation, scale_levels, min_footprint_px,
                           kernel_groups, border, tuple(origin), None if frame_shape is None else tuple(frame_shape))
    return _separable_passes(options, buffers, material, camera, kernels)


class _PassOptions(NamedTuple):
    """``_separable_impl``'s static arguments, one hashable value (``_separable_passes``' non-differentiable one)."""
    taps: int
    albedo_mode: str
    follow_surface: bool
    interpolation: str
    scale_levels: int
    min_footprint_px: float
    kernel_groups: tuple[int, ...] | None
    border: str
    origin: tuple[int, int]
    frame_shape: tuple[int, int] | None


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _separable_passes(options: _PassOptions, buffers: Buffers, material, camera: Camera,
                      kernels: tuple[Array, Array, Array | None] | None) -> Array:
    """The pass (``_separable_body``), its taps fused as ``tap_chunks`` fuses them for speed; its derivatives (the
    JVP rule, and reverse mode through it) evaluate the same pass, the same sums in chunks of
    ``_TAPS_PER_DERIVATIVE_CHUNK`` taps: a program XLA compiles several times faster, and runs no slower, where it
    is differentiated (the comment above ``_TAPS_PER_DERIVATIVE_CHUNK``). The value beside a derivative is that
    evaluation's: the same as the call's but for the sums' rounding."""
    return _separable_body(options, buffers, material, camera, kernels)


@_separable_passes.defjvp
def _separable_passes_jvp(options: _PassOptions, primals, tangents):
    return jax.jvp(functools.partial(_separable_body, options, derivative=True), primals, tangents)


def _separable_body(options: _PassOptions, buffers: Buffers, material, camera: Camera,
                    kernels: tuple[Array, Array, Array | None] | None, *, derivative: bool = False) -> Array:
    (taps, albedo_mode, follow_surface, interpolation, scale_levels, min_footprint_px, kernel_groups, border, origin,
     frame_shape) = options
    dtype = _work_dtype(buffers.irradiance.dtype)
    prep = _prepare(buffers, material.albedo, albedo_mode, dtype)
    rows = prep.rows
    if kernel_groups is not None:  # materials with one kernel share it: one kernel, one weight term per group
        rows = jnp.asarray(kernel_groups, jnp.int32)[rows]
    if kernels is None:  # traced parameters: built here, so gradients reach them (the cut's table where it runs)
        offsets, weights = _pass_kernels(material, taps, dtype, kernel_groups)
        kernels = offsets, weights, lambda: _pass_cut_table(material, taps, dtype, kernel_groups, weights)
    offsets, weights = kernels[0].astype(dtype), kernels[1].astype(dtype)  # (K, n) mm, (K, n, 3)
    mm_per_unit = camera.mm_per_unit.astype(dtype)
    ppm = px_per_mm(prep.depth, focal_px=camera.focal_px.astype(dtype), mm_per_unit=mm_per_unit)
    ppm = jnp.where(prep.valid, ppm, 0.0)
    table_reach_mm = jnp.max(jnp.abs(offsets), axis=-1)  # (M,): every kernel is its reach times one tap pattern
    count = offsets.shape[0]
    onehot = (rows[None] == jnp.arange(count)[:, None, None]).astype(dtype) if count > 1 else None  # (M, H, W)
    per_pixel = lambda table: table[0] if count == 1 else sum(onehot[m] * table[m] for m in range(count))
    reach_mm = jnp.broadcast_to(per_pixel(table_reach_mm), ppm.shape)  # (H, W)
    reach_px = reach_mm * ppm
    ok_reach = table_reach_mm > 0
    inv_reach_mm = jnp.where(ok_reach, 1.0 / jnp.where(ok_reach, table_reach_mm, 1.0), 0.0)  # (M,)
    # pixels whose footprint is below min_footprint_px keep their local shading: no pass runs for them
    active = prep.valid & (reach_px >= min_footprint_px) & (reach_px > 0)
    skip = ~active
    # levels: per material row, geometric between the smallest and the largest reach among its active pixels
    log_r = _safe_log(reach_px)
    big = jnp.asarray(jnp.finfo(dtype).max, dtype)
    of_row = active[None] & (onehot > 0) if count > 1 else active[None]  # (M, H, W)
    # least and largest in one reduction (two would each write the (M, H, W) selection out first: 3x the time)
    lo, neg_hi = jax.lax.reduce((jnp.where(of_row, log_r[None], big), jnp.where(of_row, -log_r[None], big)),
                                (big, big), lambda a, b: (jnp.minimum(a[0], b[0]), jnp.minimum(a[1], b[1])), (1, 2))
    hi = -neg_hi
    any_active = lo < big
    lo, hi = jnp.where(any_active, lo, 0.0), jnp.where(any_active, hi, 0.0)
    span = hi - lo
    nlev = scale_levels
    lo_px, span_px = per_pixel(lo), per_pixel(span)
    ok_span = span_px > 0
    t = jnp.where(ok_span, (log_r - lo_px) / jnp.where(ok_span, span_px, 1.0), 0.0) * (nlev - 1)
    t = jnp.clip(t, 0.0, nlev - 1)
    levels = jnp.arange(nlev, dtype=dtype)
    level_weights = jnp.maximum(0.0, 1 - jnp.abs(t[None] - levels[:, None, None]))
    level_weights = jnp.where(active[None], level_weights, 0.0)
    level_reach_px = jnp.exp(lo[:, None] + span[:, None] * levels[None] / max(nlev - 1, 1))  # (M, L)
    level_reach_px = jnp.where(any_active[:, None], level_reach_px, 0.0)
    unit_offsets = jnp.asarray(spec.pass_unit_offsets(taps), dtype)
    w_table = jnp.moveaxis(weights, -1, 1)  # (M, 3, n)
    common = dict(unit_offsets=unit_offsets, mm_per_unit=mm_per_unit, follow_surface=follow_surface,
                  interpolation=interpolation, border=border, skip_centre=True,  # the pass order is centre first
                  cut_table=kernels[2], derivative=derivative)
    frame_shape = tuple(buffers.depth.shape) if frame_shape is None else tuple(frame_shape)
    # planar (3, H, W): the fused loops run along rows (stacked channel slices: XLA's CPU transpose of moveaxis and
    # its layout copy take 2.5x as long at 640x360)
    e = jnp.stack([prep.irradiance[..., c] for c in range(3)])
    for axis in (2, 1):  # horizontal, then vertical
        e = _separable_pass(e, prep.depth, prep.valid, level_weights, level_reach_px, skip, onehot, w_table,
                            inv_reach_mm, axis=axis, origin_along=origin[axis - 1],
                            frame_length=frame_shape[axis - 1], **common)
    return _finish(buffers, prep, jnp.moveaxis(e, 0, -1))


def _pass_kernels(material, taps: int, dtype, kernel_groups: tuple[int, ...] | None) -> tuple[Array, Array]:
    """The pass's kernels ``(offsets_mm (K, n), weights (K, n, 3))``, one per distinct kernel (``kernel_groups``):
    each material answers for its own."""
    k = spec.distinct_kernels(material, kernel_groups).separable_kernels(taps, dtype)
    return k.offsets_mm, k.weights


def _pass_cut_table(material, taps: int, dtype, kernel_groups: tuple[int, ...] | None, weights: Array) -> Array:
    """The table of the cut at the frame ``(K, 3, knots)`` of the pass's kernels (``spec.cut_table``; ``weights
    (K, n, 3)`` theirs), each re-integrated from its material's profile."""
    return spec.material_cut_table(spec.distinct_kernels(material, kernel_groups), taps, dtype,
                                   jnp.moveaxis(weights, -1, 1))


_built_kernels = eqx.filter_jit(_pass_kernels)
_built_cut_table = eqx.filter_jit(_pass_cut_table)
_KERNELS: dict = {}
_CUT_TABLES: dict = {}


def _kernels_for(material, taps: int, dtype, kernel_groups, *, cut: bool = True
                 ) -> tuple[Array, Array, Array | None] | None:
    """An eager call's kernels and the table of their cut at the frame (``_pass_cut_table``; ``None`` where the
    caller knows that no kernel is cut: ``cut=False``), each built once per material parameters, taps, dtype and
    groups (the pre-integration of a profile is ~3 ms of a 640x360 pass on a CPU, its cut table ~1 ms, the same
    for every frame of a batch); ``None`` for parameters that are traced or a material without a parameter key (the
    pass then builds them itself, the table only where a level is cut)."""
    base = _parameter_key(material)
    if base is None:
        return None
    key = (base, taps, np.dtype(dtype).name, kernel_groups)
    kernels = _KERNELS.get(key)  # one read: another thread may empty the cache
    if kernels is None:
        kernels = _built_kernels(material, taps, dtype, kernel_groups)
        if not _is_concrete(kernels):  # called while something traces (a jit around it): staged, not kept
            return (*kernels, _built_cut_table(material, taps, dtype, kernel_groups, kernels[1]) if cut else None)
        _remember(_KERNELS, key, kernels, limit=64)  # a long fit over many parameters: bounded
    if not cut:
        return (*kernels, None)
    table = _CUT_TABLES.get(key)
    if table is None:
        table = _built_cut_table(material, taps, dtype, kernel_groups, kernels[1])
        if _is_concrete(table):  # not while something traces (staged): kept
            _remember(_CUT_TABLES, key, table, limit=64)
    return (*kernels, table)


def _may_cut(material, taps: int, frame_shape: tuple[int, int], px_per_mm: float) -> bool:
    """Host side: whether a kernel may reach past the frame in an eager call: the widest kernel at the nearest
    active depth (``px_per_mm``, ``_nearest_px_per_mm``) against the frame's shorter extent, with a margin for the
    pass's rounding."""
    return float(np.max(_cut_reach_px(material, taps, px_per_mm))) > min(frame_shape) * (1 - 1e-4)


def _cut_reach_px(material, taps: int, px_per_mm: float) -> np.ndarray:
    """Host side: each material's kernel reach as the cut at the frame sees it (its outer cells' edge), in px at
    ``px_per_mm``, ``(M,)``: what ``_may_cut`` and ``far_cut_message`` compare with the frame."""
    offsets, _ = _host_kernels(material, taps)
    return np.max(np.abs(offsets), axis=-1) * px_per_mm * spec.cell_edge(taps)


# ``far_cut_message``: past this ratio of the widest kernel's reach to the frame's shorter extent, the kernel cut at
# the frame is no longer the re-integrated profile: its cells' masses (differences of the cut table near 0, in the
# pass's dtype) lose their precision and the formulations part (the demo frame, Burley d = d/3 = 0: the gather and the
# banded pass within 1e-3 up to a ratio of 6e5 (d 1e7 mm), 0.012 at 6e6, and at 6e7 the output jumps to a limit that
# holds no trace of the profile; a table of 16 decades instead of 8 moved that by one decade only)
FAR_CUT_RATIO = 1e6


def far_cut_message(material, taps: int, frame_shape: tuple[int, int], px_per_mm: float) -> str | None:
    """Host side: what to say where the widest kernel, at the nearest active depth, reaches more than
    ``FAR_CUT_RATIO`` times the frame's shorter extent (a d of ~1e7 mm on a close-up: a unit gone wrong, or a fit
    that wandered): there its cut at the frame loses its precision. ``None`` where it does not."""
    if not px_per_mm > 0:
        return None
    widest = _cut_reach_px(material, taps, px_per_mm)
    ratio = float(np.max(widest)) / min(frame_shape)
    if not ratio > FAR_CUT_RATIO:
        return None
    m = int(np.argmax(widest))
    return (f"separable: material {m + 1}'s kernel reaches {float(widest[m]):.3g} px, {ratio:.2g} times the frame's "
            f"shorter extent: past {FAR_CUT_RATIO:.0e} its cut at the frame loses its precision, and the result "
            f"is not the profile's (is d in mm?)")


def sampling_messages(buffers: Buffers, material, camera: Camera, taps: int, min_footprint_px: float,
                      frame_shape: tuple[int, int], px_per_mm: float | None = None) -> list[str]:
    """Host side: what ``separable`` warns of for these buffers (``SamplingWarning``s; the technique's ``check``
    lists the same): tap cells too coarse for a hard edge at the widest reach (``separable_edge_error``, beyond
    ``SAMPLING_ERROR_LIMIT``), and a reach so far past the frame that its cut loses its precision
    (``far_cut_message``). ``px_per_mm``: the nearest active depth's, where the caller has read it already."""
    ppm = _nearest_px_per_mm(buffers, camera) if px_per_mm is None else px_per_mm
    said = []
    implied = separable_edge_error(buffers, material, camera, int(taps), float(min_footprint_px), px_per_mm=ppm)
    if implied[0] > SAMPLING_ERROR_LIMIT:
        said.append(f"separable: {taps} taps at a reach of {implied[1]:.0f} px leave tap cells up to "
                    f"{implied[2]:.1f} px wide: a hard edge may be off by up to {implied[0]:.3f} of its contrast "
                    f"(more taps lower it)")
    far = far_cut_message(material, int(taps), frame_shape, ppm)
    if far is not None:
        said.append(far)
    return said


def _nearest_px_per_mm(buffers: Buffers, camera: Camera) -> float:
    """Host side: px per mm at the active pixel nearest the camera (0 where none is active)."""
    depth = np.asarray(buffers.depth)  # the buffer's own type: its least valid depth is one of its values
    valid = surface_mask(depth)  # NumPy in, NumPy out
    if buffers.material_id is not None:
        valid &= np.asarray(buffers.material_id) > 0
    nearest = float(np.min(depth, where=valid, initial=np.inf))
    return float(camera.focal_px) / (nearest * float(camera.mm_per_unit)) if np.isfinite(nearest) else 0.0


def separable(
    buffers: Buffers,
    material: TwoGaussianMaterial | BurleyMaterial | ProfileMaterial,
    camera: Camera,
    *,
    taps: int = 25,
    albedo_mode: str = "post",
    follow_surface: bool = True,
    interpolation: str = "linear",
    min_footprint_px: float = MIN_FOOTPRINT_PX,
    scale_levels: int = SCALE_LEVELS,
    impl: str = "auto",
    border: str = "renormalise",
    origin: tuple[int, int] = (0, 0),
    frame_shape: tuple[int, int] | None = None,
) -> Float[Array, "H W 3"]:
    """Separable subsurface scattering (Jimenez et al. 2015): a horizontal then a vertical 1D pass.

    The kernel is the artist-friendly two-Gaussian model (``TwoGaussianMaterial``) or the pre-integrated kernel of a
    profile (``BurleyMaterial``, ``ProfileMaterial``), ``taps`` taps per pass placed densest near the centre, offsets
    in mm projected per pixel by its depth. Weights sum to 1, so energy is redistributed, not created; with
    ``follow_surface`` each pixel a tap reads counts less as its depth differs from the centre's and, at a difference
    as large as the kernel's reach, counts as the centre colour, so light does not cross depth discontinuities (the
    two pixels of a linear fetch are tested separately: no interpolated depth between the sides of a step).
    ``interpolation``: "linear" (continuous in the offsets, for fitting) or "nearest".

    Cost: each pass is ``taps`` constant shifts of the padded image per reach level (fused loops, no per-pixel
    gathers), over blocks of the frame (bands of rows cut into 128 columns): a block computes only the (material,
    level) pairs its own pixels use, so the cost follows the scene's coverage. The reach in px varies with depth and
    material; each material's reach is quantised into ``scale_levels`` geometric levels between its own smallest and
    largest reach in the frame, and each pixel blends the two levels of its material bracketing its own reach (exact
    where a material has one reach, or two; levels no pixel uses are skipped). Pixels whose footprint (the radius
    holding 99% of the widest channel's energy, in px) is below ``min_footprint_px`` keep their local shading
    (``albedo * irradiance``, the paper's Fig. 1); 0 disables that. Several materials in one frame cost one pass;
    materials that share a kernel (differing only in albedo) share its table row and per-pixel weight term.

    Light that scatters out of the frame leaves: a tap (or the part of a linear fetch) landing off the image counts as
    dark, so each pass keeps, of a pixel's light, the share of the 1D kernel inside the frame (the 2D pass: the
    product of the two shares). A kernel whose reach exceeds the frame's extent along a pass is cut there (the rest
    leaves from every pixel) and its taps spread over the frame (``frame_truncation``): as d grows past the frame the
    light spreads over it and out, never back onto its own pixel. With concrete inputs, where the taps' cells at the
    widest reach are too coarse for a hard edge, a ``SamplingWarning`` states the error they imply
    (``separable_edge_error``). That is ``border="leaves"``; the default, ``border="renormalise"``, counts
    off-image taps as the centre instead (the kernel cut at the frame renormalised), as if the surface beyond looked
    like the inside: what engines do, and the better rule on path-traced frames (README, "Defaults on real
    frames"). Jimenez's shader does neither: its sampler clamps, so an off-image tap reads the edge texel (the
    ``jimenez`` technique).

    ``impl`` (``_dispatch``): "banded" is the formulation above (what "auto" runs on a CPU); "gather" is the whole
    frame with per tap a gather at each pixel's own offset (Jimenez's shader, so no reach levels and no level error;
    ``scale_levels`` unused; "auto" off a CPU), "pallas" that as a Pallas kernel per pass. All three run one spec
    (``_separable_spec``: tap offsets, fetches, the fetched pixel's weight, the per-tap term, the cut at the frame)
    and implement every option; they agree exactly where each material has one reach in the frame (or two: the
    banded levels sit at its least and largest), and the banded one approaches the gather as ``scale_levels`` grows
    (demo scene, 640x360, three materials: rel. L2 between them 0.0005).
    "xla-cpu"/"xla-gpu" are the old names of "banded"/"gather".

    ``origin`` (the buffer's top-left pixel in the whole frame) and ``frame_shape`` (the frame's ``(H, W)``) place a
    tile: the border and the cut of wide kernels follow the frame, so a tile cropped with a halo of
    ``Separable.reach_px`` gives the frame's pixels with "gather"/"pallas"; with "banded" only where the tile holds
    each material's least and largest reach in the frame (its levels are its buffer's), so "auto" on a CPU refuses a
    tile ("cannot place a tile": a batch runs such frames whole) rather than give other pixels than the frame. Host
    work per eager call of "banded": the sampling check (``separable_edge_error``: NumPy over the depth and ids, the
    bound kept per kernels, shape and nearest depth) and ``kernel_groups``; the kernels are built once per material
    parameters and taps (traced parameters build them inside the pass); the whole-frame layouts read nothing back.
    Buffers held on the host are checked first, as by every technique (``validate_buffers``; ``burley`` says more).
    """
    _check_border(border)
    _check_albedo_mode(albedo_mode)
    check_one_image("separable", buffers, getattr(material, "count", None), camera=camera)
    if not isinstance(material, AbstractMaterial):
        raise TypeError("separable needs a TwoGaussianMaterial, BurleyMaterial or ProfileMaterial, got "
                        + type(material).__name__)
    if interpolation not in ("linear", "nearest"):
        raise ValueError(f"interpolation={interpolation!r} is not one of ('linear', 'nearest')")
    check_separable_counts(taps, scale_levels, min_footprint_px)
    mode = "bilinear" if interpolation == "linear" else "nearest"
    which = resolve_impl(impl, "separable", dict(border=border, interpolation=interpolation))
    origin, frame_shape = check_tile(tuple(buffers.depth.shape[-2:]), origin, frame_shape)
    if impl == "auto" and which == "banded" and (origin != (0, 0) or frame_shape != tuple(buffers.depth.shape[-2:])):
        # the banded levels are the buffer's least and largest reach: a tile's may differ from its frame's, and so
        # its pixels; "auto" gives the same pixels tiled or not (a batch then runs the frame whole)
        raise TilePlacementError("separable cannot place a tile with impl='auto' on a CPU: the banded formulation's reach "
                         "levels are its buffer's, so a tile would differ from its frame by the levels' error; pass "
                         "the whole frame, or impl='gather' for the frame and its tiles")
    if which != "banded":  # no host read of the parameters (kernel_groups) off the CPU
        return separable_gpu_impl(buffers, material, camera, int(taps), albedo_mode, bool(follow_surface), mode,
                                  float(min_footprint_px), None, which, border, origin, frame_shape)
    concrete = _is_concrete(buffers, material, camera)
    ppm = _nearest_px_per_mm(buffers, camera) if concrete else None  # the host reads the depth once
    if concrete:  # a host-side check: the CPU formulation only, which counts anyway
        for message in sampling_messages(buffers, material, camera, int(taps), float(min_footprint_px), frame_shape,
                                         px_per_mm=ppm):
            warnings.warn(message, SamplingWarning, stacklevel=2)
    groups = kernel_groups(material)
    cut = ppm is None or _may_cut(material, int(taps), frame_shape, ppm)  # no table where no kernel is cut
    return _separable_impl(buffers, material, camera, int(taps), albedo_mode, bool(follow_surface), mode,
                           int(scale_levels), float(min_footprint_px), groups, border, origin, frame_shape,
                           _kernels_for(material, int(taps), _work_dtype(buffers.irradiance.dtype), groups, cut=cut))


def separable_edge_error(buffers: Buffers, material, camera: Camera, taps: int,
                         min_footprint_px: float = MIN_FOOTPRINT_PX, *, px_per_mm: float | None = None
                         ) -> tuple[float, float, float]:
    """Host side: what the taps' resolution implies for the widest kernel in the frame (the active pixel nearest the
    camera): ``(error, reach_px, widest_cell_px)``, where ``error`` bounds how far a hard edge's profile can be from
    the kernel's, as a fraction of the edge's contrast. A tap stands for the kernel's mass over its cell; with linear
    fetches a cell up to a pixel wide is resolved, a wider one moves its whole mass at once as the edge crosses it, by
    up to ``w_i (1 - 1 / cell_i) / 2`` (half way across, on average); the largest over the taps of either pass (after
    ``frame_truncation``), is the bound. NumPy throughout; the bound is kept per kernels, frame shape and nearest
    depth (an eager call of the same material on the next frame reads its depth and ids, nothing more;
    ``px_per_mm``: the nearest active depth's, where the caller has read it already)."""
    ppm = _nearest_px_per_mm(buffers, camera) if px_per_mm is None else px_per_mm
    if ppm == 0:
        return 0.0, 0.0, 0.0
    key, (offsets, weights) = _host_kernels(material, taps, with_key=True)
    shape = tuple(buffers.depth.shape[-2:])
    memo_key = None if key is None else (key, shape, ppm, float(min_footprint_px))
    known = None if memo_key is None else _EDGE_ERRORS.get(memo_key)  # one read: another thread may empty it
    if known is not None:
        return known
    reach_mm = np.max(np.abs(offsets), axis=-1)  # (M,)
    worst = (0.0, 0.0, 0.0)
    unit = spec.pass_unit_offsets(taps)
    bounds = spec.cell_bounds(taps)
    order = np.argsort(spec.tap_order(taps))
    edge = spec.cell_edge(taps)
    for m in range(offsets.shape[0]):
        reach_px = float(reach_mm[m]) * ppm
        if reach_px < min_footprint_px or reach_px <= 0:
            continue
        w_m = np.moveaxis(weights[m:m + 1], -1, 1)  # (1, 3, n)
        for extent in set(shape):
            scale, w_pass = 1.0, w_m[0]
            if reach_px * edge > extent:  # cut at the frame (a close-up): the table built once per parameters
                cut_scale, w_levels = frame_truncation(unit, w_m, np.asarray([reach_px]), float(extent),
                                                       _host_cut_table(material, taps, key, weights)[m:m + 1])
                scale, w_pass = float(cut_scale[0]), w_levels[0, 0]
            w_sorted = w_pass[:, order]  # (3, n) ascending offsets
            cells = np.diff(bounds) * scale * reach_px
            error = float(np.max(w_sorted * np.maximum(0.0, 1 - 1 / np.maximum(cells, 1e-12)) / 2))
            if error > worst[0]:
                worst = (error, reach_px, float(np.max(cells)))
    if memo_key is not None:
        _remember(_EDGE_ERRORS, memo_key, worst)  # many frames of varying depth: bounded
    return worst


def _remember(cache: dict, key, value, *, limit: int = 256):
    """``value``, kept under ``key`` in one of the eager call's host caches, which empties once it holds more than
    ``limit`` entries (a long fit over many parameters, or many frames of varying depth, keeps it bounded)."""
    if len(cache) > limit:
        cache.clear()
    cache[key] = value
    return value


_EDGE_ERRORS: dict = {}
_HOST_KERNELS: dict = {}


def _parameter_key(material):
    """Host side: a key naming a material's kernel parameters (type, shapes, bytes), or ``None`` where they are
    traced or the material has none: what the per-parameter caches of an eager call (host kernels, the pass's
    kernels, the sampling bound, the kernel groups) are keyed on."""
    last = _LAST_KEY.get("last")  # (material, key) in one slot: calls in two threads (a batch) never mix them
    if last is not None and last[0] is material:  # an eager call asks three times (groups, kernels, sampling bound)
        return last[1]
    # through the class: a method read off an equinox Module builds a bound-method Module (~0.03-0.07 ms a call)
    params = type(material).kernel_parameters(material)
    if params is None or not _is_concrete(params):
        return None
    key = (type(material).__name__, tuple((np.shape(p), np.asarray(p).tobytes()) for p in params))
    if all(isinstance(p, jax.Array) for p in params):  # immutable: the key holds while the object lives (kept here)
        _LAST_KEY["last"] = (material, key)
    return key


_LAST_KEY: dict = {}


def _host_kernels(material, taps: int, *, with_key: bool = False):
    """Host side: the material's separable kernels ``(offsets_mm (M, n), weights (M, n, 3))`` in float64, built once
    per material parameters and tap count (the sampling check runs on every eager call: building the kernels
    eagerly each time is ~100 small dispatches). ``with_key``: ``(key, kernels)``, the key naming the parameters
    (``None`` where they are traced or the material has none)."""
    base = _parameter_key(material)
    key = None if base is None else (base, taps)
    out = None if key is None else _HOST_KERNELS.get(key)  # one read: another thread may empty the cache
    if out is None:
        kernels = _host_kernel_build(material, taps, jax.dtypes.canonicalize_dtype(jnp.float64))
        out = np.asarray(kernels.offsets_mm, np.float64), np.asarray(kernels.weights, np.float64)
        if key is not None:
            _remember(_HOST_KERNELS, key, out)  # a long fit over many parameters: bounded
    return (key, out) if with_key else out


# the host kernels as one compiled program: built eagerly they were ~75 small dispatches, each compiled on its first
# use, ~2 s of a process's first separable call (4.6-5.1 -> 2.5-3.0 s; most of the bench's compile_seconds)
_host_kernel_build = eqx.filter_jit(lambda material, taps, dtype: material.separable_kernels(taps, dtype))
_HOST_CUT_TABLES: dict = {}


def _host_cut_table(material, taps: int, key, weights: np.ndarray) -> np.ndarray:
    """Host side: the table of the material's kernels cut at the frame ``(M, 3, knots)`` in float64
    (``spec.cut_table``; ``weights``: the kernels' own, ``_host_kernels``'), built once per material parameters and
    tap count (``key``, ``_host_kernels``' key, or ``None``: not kept)."""
    out = None if key is None else _HOST_CUT_TABLES.get(key)  # one read: another thread may empty the cache
    if out is None:
        dtype = jax.dtypes.canonicalize_dtype(jnp.float64)
        out = np.asarray(_built_cut_table(material, taps, dtype, None, jnp.asarray(weights, dtype)), np.float64)
        if key is not None:
            _remember(_HOST_CUT_TABLES, key, out)
    return out


def kernel_groups(material) -> tuple[int, ...] | None:
    """Host side: for a table of several materials of which some share one separable kernel (the same d, or the
    same two-Gaussian w and sigmas; the albedo may differ), the group of each material (groups numbered in order of
    first appearance), so ``separable`` builds and weights each distinct kernel once; ``None`` where every kernel is
    distinct, for one material, or for traced parameters."""
    params = type(material).kernel_parameters(material)  # through the class, as _parameter_key
    if params is None or not _is_concrete(params) or np.ndim(params[0]) < 2 or np.shape(params[0])[0] < 2:
        return None
    memo = _parameter_key(material)
    known = _GROUPS.get(memo, _GROUPS)  # one read (another thread may empty the cache); None is a cached answer
    if known is not _GROUPS:
        return known
    key = np.concatenate([np.asarray(p).reshape(np.shape(params[0])[0], -1) for p in params], axis=1)
    groups: dict[bytes, int] = {}
    out = tuple(groups.setdefault(row.tobytes(), len(groups)) for row in key)
    out = out if len(groups) < len(out) else None
    return _remember(_GROUPS, memo, out)


_GROUPS: dict = {}

