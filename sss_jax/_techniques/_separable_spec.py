"""``separable`` written once: where a tap lands, what a fetched pixel counts for, the per-tap term, and the kernel
cut at the frame.

Every formulation of the 1D pass (``_separable``: bands of constant shifts at quantised reach levels;
``_separable_gpu``: the whole frame, a gather per tap at each pixel's own offset; ``_pallas``: that gather in blocks of
pixels) evaluates these functions on its own layout; they differ in which reach a pixel's taps use (a level's or the
pixel's own) and in how they fetch, not in arithmetic.

One pass at a pixel with irradiance ``e``, depth ``z``, kernel reach ``R`` px and tap weights ``w_i`` (per channel)
at unit offsets ``u_i`` (``_kernels.unit_tap_offsets``, centre first) is::

    out = e sum_i w_i + sum_i w_i sum_q f_q (keep_q (e_q - e) - out_q e)

over the pixels q tap i fetches at ``u_i R`` px along the pass (one for "nearest", two with weights ``1 - f`` and
``f`` for "linear"). ``keep_q`` is 0 for a pixel that takes no part and, with ``follow_surface``,
``max(1 - |z_q - z| mm_per_unit / reach_mm, 0)`` otherwise (Jimenez's "follow the surface": none at the kernel's
reach); ``out_q`` is 1 where q lies outside the frame and the border is "leaves" (that light leaves: the tap counts
as dark), else 0 (the tap counts as the centre: "renormalise").

A kernel whose outer tap cell reaches past the frame's extent along the pass is cut there (``truncation_scale``):
its taps spread over ``[-extent, extent]`` in the same pattern, each weighing the kernel's mass over its shrunk cell
(re-integrated from each channel's profile: ``cut_table``, ``cut_cumulative``); with "renormalise" the cut kernel
keeps the full kernel's total. Positions are frame coordinates: a buffer that is a tile of a larger frame states its
first pixel along the pass in the frame, and the frame's extent decides both the border and the cut.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._kernels import centre_first, unit_tap_offsets


def tap_order(taps: int) -> np.ndarray:
    """The pass's tap order (centre first), as indices into the ascending pattern."""
    return np.asarray(centre_first(taps)) if taps > 1 else np.zeros(1, int)


def pass_unit_offsets(taps: int) -> np.ndarray:
    """The unit tap offsets in the pass's order (centre first), float64."""
    return np.asarray(unit_tap_offsets(taps))[tap_order(taps)]


def cell_bounds(taps: int) -> np.ndarray:
    """The boundaries ``(taps + 1,)`` (ascending, unit offsets) of the cells the taps stand for: half way between
    neighbouring taps, the outer cells as wide beyond the last tap as inside it (one tap: ``[-0.5, 0.5]``)."""
    if taps == 1:
        return np.array([-0.5, 0.5])
    sorted_unit = np.sort(np.asarray(unit_tap_offsets(taps)))
    mids = 0.5 * (sorted_unit[1:] + sorted_unit[:-1])
    outer = 2 * sorted_unit[-1] - mids[-1]
    return np.concatenate([[-outer], mids, [outer]])


@functools.lru_cache(maxsize=64)
def cell_edge(taps: int) -> float:
    """Where the outer cells end, in units of the reach (the kernel's extent as the taps see it); a float, kept per
    count (an eager call asks it each time)."""
    return float(cell_bounds(taps)[-1])


def truncation_scale(reach_px, edge: float, extent_px):
    """By how much a kernel of reach ``reach_px`` shrinks to fit the frame's extent along the pass: 1 where its outer
    cells end within ``extent_px``, else ``extent_px / (reach_px edge)``. NumPy or JAX arrays alike."""
    xp = np if isinstance(reach_px, (np.ndarray, float, int)) else jnp
    reach_edge = reach_px * edge
    fits = reach_edge <= extent_px
    return xp.where(fits, 1.0, extent_px / xp.where(fits, 1.0, reach_edge))


# The kernel cut at the frame is re-integrated from each channel's own profile (``cut_table``): its cumulative mass at
# fixed unit positions, 0 and then geometric from 1e-8 of the outer cells' edge to the edge, KNOTS_PER_DECADE per
# decade, linear between them; the mass within the first knot counts as at 0 (a wide channel holds ~1e-7 of itself
# there; a channel 1000x narrower than its material's widest, ~1e-4). Fine near 0, so a channel whose mass sits at the
# centre (d = 0, sigma 0, or merely narrow beside a wide channel of its material) keeps it in the centre tap's shrunk
# cell however far the kernel is cut; the taps' own cells are far too coarse for that (read linearly within them, the
# centre cell's mass spread over every shrunk cell inside it: a d = 0 channel lost the identity, its centre weight
# falling to the shrink factor). Geometric, so a position's interval is one logarithm.
KNOTS_PER_DECADE = 32
KNOT_DECADES = 8


def cut_knots(taps: int) -> np.ndarray:
    """The unit positions ``(K + 1,)`` (ascending, float64) of the cut's table: 0, then ``edge 10^(-i /
    KNOTS_PER_DECADE)`` from ``i = KNOTS_PER_DECADE KNOT_DECADES`` down to 0 (the last is the cell edge)."""
    count = KNOTS_PER_DECADE * KNOT_DECADES
    return np.concatenate([[0.0], cell_edge(taps) * 10.0 ** (np.arange(-count, 1) / KNOTS_PER_DECADE)])


def cut_table(half_masses, w_table):
    """The cut's table ``(..., 3, K + 1)`` from a kernel's masses over ``[0, x]`` at the positive knots
    (``half_masses (..., 3, K)``: the material's ``separable_half_masses(cut_knots(n)[1:])``) and its tap weights
    ``(..., 3, n)``: 0 at 0, the masses inside, half the weights' total at the edge (the mass beyond the outer cells'
    edge counts there, as the uncut kernel's outer taps hold it, so the cut starts from the whole kernel). NumPy or
    JAX arrays alike."""
    xp = np if isinstance(half_masses, np.ndarray) else jnp
    zero = xp.zeros(half_masses.shape[:-1] + (1,), half_masses.dtype)
    half_total = 0.5 * xp.sum(w_table, axis=-1, keepdims=True).astype(half_masses.dtype)
    return xp.concatenate([zero, half_masses[..., :-1], half_total], axis=-1)


def distinct_kernels(material, kernel_groups: tuple[int, ...] | None):
    """The material table with one row per distinct kernel (``kernel_groups``: the group of each material, groups
    numbered in order of first appearance; each kernel is then built once), or the table itself (``None``)."""
    if kernel_groups is None:
        return material
    first = np.asarray([kernel_groups.index(g) for g in range(max(kernel_groups) + 1)])
    return jax.tree.map(lambda a: a[first], material)


def material_cut_table(material, taps: int, dtype, w_table):
    """``cut_table`` of a material table's kernels (``w_table (M, 3, n)`` their weights): each re-integrated from
    its own profile, ``material.separable_half_masses`` at ``cut_knots``."""
    half = material.separable_half_masses(cut_knots(taps)[1:], dtype).astype(dtype)
    return cut_table(half, w_table.astype(dtype))


def knot_index(x, taps: int):
    """The interval ``[k_j, k_j+1]`` of ``cut_knots`` holding the unit position ``x >= 0`` (int32, 0 to K - 1): one
    logarithm (the knots are geometric); 0 below the first positive knot, the last at the edge. NumPy or JAX."""
    xp = np if isinstance(x, (np.ndarray, float, int)) else jnp
    count = KNOTS_PER_DECADE * KNOT_DECADES
    edge = cell_edge(taps)
    tiny = edge * 10.0 ** -(KNOT_DECADES + 1)
    j = xp.floor(1 + count + KNOTS_PER_DECADE * xp.log10(xp.maximum(x, tiny) / edge))
    return xp.clip(j, 0, count).astype(xp.int32)


def cut_cumulative(x, taps: int, knot_at, value_at):
    """A cut kernel's mass over ``[0, x]`` (negative for ``x < 0``: the kernel is symmetric) at unit position ``x``
    (``|x|`` at most the edge): the table linear between knots, the first knot's value from 0 on (the mass that
    close to 0 counts as at 0). ``knot_at(j)``: the knots (``cut_knots``); ``value_at(j)``: the table's values at
    knot ``j`` (``cut_table``), in whatever layout the caller keeps them."""
    xp = np if isinstance(x, (np.ndarray, float, int)) else jnp
    a = xp.abs(x)
    j = knot_index(a, taps)
    k0, k1 = knot_at(j), knot_at(j + 1)
    v0, v1 = value_at(j), value_at(j + 1)
    t = xp.where(j == 0, 1.0, (a - k0) / (k1 - k0))
    return xp.sign(x) * (v0 + (v1 - v0) * t)


def tap_offset(unit, reach_px, limit):
    """Where a tap lands, px along the pass from its pixel: ``unit * reach_px``, clipped to ``[-limit, limit]``
    (``limit`` is just beyond the buffer: a clipped tap still lands outside it)."""
    return jnp.clip(unit * reach_px, -limit, limit)


def fetch_corners(off, interpolation: str) -> list[tuple[Array, Array | None]]:
    """The pixels a tap at fractional offset ``off`` reads: ``[(shift, fraction)]`` (integer shifts, ``None`` for a
    whole pixel). "nearest": the rounded offset; "linear"/"bilinear": the two pixels around it, ``1 - f`` and ``f``."""
    if interpolation == "nearest":
        return [(jnp.round(off).astype(jnp.int32), None)]
    x0 = jnp.floor(off)
    f = off - x0
    start = x0.astype(jnp.int32)
    return [(start, 1 - f), (start + 1, f)]


# A depth at which a fetched pixel counts for nothing: a layout may store the pixels that take no part (and the
# padding beyond the buffer) at this depth instead of fetching a validity plane (``fetch_keep`` with ``v_q=None``).
# Any centre depth and follow-the-surface scale above 1e-30 put such a pixel beyond the kernel's reach (a product
# that overflows to inf gives 0 all the same).
FAR = 1e30


def fetch_keep(z_q, v_q, z, scale, *, follow_surface: bool):
    """How much a fetched pixel counts (0 to 1): ``v_q`` (1 where it takes part and lies in the buffer, else 0) and,
    with ``follow_surface``, less as its depth ``z_q`` differs from the centre's ``z``, none at ``1 / scale``
    (``scale = mm_per_unit / reach_mm``). No division: with v in {0, 1}, ``v (1 - clip(|z_q - z| scale))`` is
    ``max(v - |z_q - v z| scale, 0)`` (where v is 0 the second term is never negative: ``z_q`` may be anything).
    ``v_q=None``: the validity travels in the depth (``FAR`` where the pixel takes no part), so
    ``max(1 - |z_q - z| scale, 0)`` is the same number without a validity plane; ``scale=None`` with it: both
    depths come multiplied by the scale already (one number per material: a layout that runs one material at a
    time scales its depth planes once)."""
    if v_q is None:
        if not follow_surface:
            return (z_q < FAR).astype(z.dtype)
        return jnp.maximum(1.0 - jnp.abs(z_q - z) * (1.0 if scale is None else scale), 0.0)
    if not follow_surface:
        return v_q
    return jnp.maximum(v_q - jnp.abs(z_q - v_q * z) * scale, 0.0)


def tap_sums(fetched: Sequence[tuple[Array | Sequence[Array], Array, Array | None, Array | None, Array | None]],
             z: Array, scale: Array | None, *, follow_surface: bool, planar: bool
             ) -> tuple[Array | list[Array], Array, Array | None]:
    """What one tap gathers, before its weight: ``(sum_q f_q keep_q e_q`` per channel, ``sum_q f_q keep_q``,
    ``sum_q f_q out_q)`` (the last ``None`` where no ``out_q`` is given: no light leaves).

    ``fetched``: per pixel q the tap reads, ``(e_q, z_q, v_q, out_q, f_q)`` (``v_q`` ``None``: validity in the depth,
    see ``fetch_keep``; ``out_q`` 1 outside the frame where light leaves, else 0, or ``None``; ``f_q`` ``None`` for
    a whole pixel). ``e_q`` planar (channels on a leading axis: the banded layout, whose fused loops want one
    expression) where ``planar``, else a sequence of planes (the whole-frame layouts and Pallas blocks).

    The pass is then ``pass_value``: the per-tap term ``sum_q f_q (keep_q (e_q - e) - out_q e)`` of the module
    docstring, weighted and summed over the taps, is ``A - e (K + O)`` with A, K, O these sums weighted and summed;
    the centre enters once per pass instead of once per fetch."""
    kept_e = kept = left = None
    for e_q, z_q, v_q, out_q, frac in fetched:
        keep = fetch_keep(z_q, v_q, z, scale, follow_surface=follow_surface)
        if frac is not None:
            keep = frac * keep
            out_q = None if out_q is None else frac * out_q
        ke = keep[None] * e_q if planar else [keep * a for a in e_q]
        kept_e = ke if kept_e is None else (kept_e + ke if planar else [a + b for a, b in zip(kept_e, ke)])
        kept = keep if kept is None else kept + keep
        if out_q is not None:
            left = out_q if left is None else left + out_q
    return kept_e, kept, left


# The centre tap (unit offset 0, the pass's first) reads the pixel itself, which takes part at its own depth: keep 1,
# so it adds ``w_0 e`` to A and ``w_0`` to K, and ``pass_value`` gets ``e w_0 - e w_0``: nothing. A layout may skip
# its fetch (the banded one does); the weight total keeps ``w_0``.


def pass_value(e, weight_sum, kept_e, kept, left=None):
    """A pass's value at a pixel from its centre ``e``, the tap weights' total and the weighted sums of ``tap_sums``
    (``A``, ``K``, ``O``): ``e (weight_sum - K - O) + A``, which is ``e sum_i w_i + sum_i w_i sum_q f_q (keep_q (e_q
    - e) - out_q e)``. Any layout (planar arrays or one channel's planes)."""
    lost = kept if left is None else kept + left
    return e * (weight_sum - lost) + kept_e


def frame_truncation(unit_offsets: Array | np.ndarray, w_table: Array | np.ndarray,
                     level_reach_px: Array | np.ndarray, extent_px: float, table: Array | np.ndarray
                     ) -> tuple[Array | np.ndarray, Array | np.ndarray]:
    """Per reach level, the scale of the tap pattern and the tap weights ``(L, M, 3, n)`` of a kernel cut at the
    frame's extent along the pass (``extent_px``: no offset beyond it lands in the frame from any pixel).

    A kernel whose outermost tap cell reaches past the extent is replaced by its part inside ``[-extent, extent]``,
    taps spread over that range in the same pattern: tap i gets the kernel's mass over its shrunk cell, re-integrated
    from each channel's profile (``cut_cumulative`` of ``table (M, 3, K + 1)``, ``cut_table``), and the mass beyond
    the extent is dropped (it leaves the frame from every pixel). Without this a kernel far wider than the frame puts
    every tap but the centre outside it, and the pass returns the input scaled by the centre weight instead of
    spreading the light. Kernels within the extent are unchanged. ``unit_offsets`` and ``w_table (M, 3, n)`` are in
    the pass's tap order (centre first)."""
    n = unit_offsets.shape[0]
    order = tap_order(n)
    xp = np if isinstance(w_table, np.ndarray) else jnp  # NumPy for the host check: no dispatch per call
    dtype = w_table.dtype
    bounds = xp.asarray(cell_bounds(n), dtype)
    knots = xp.asarray(cut_knots(n), dtype)
    scale = truncation_scale(level_reach_px, cell_edge(n), extent_px)  # (L,)
    fits = scale >= 1.0
    # the cumulative masses at the shrunk boundaries: one knot interval per level and boundary, shared by every
    # material and channel (no vmap: NumPy runs it too)
    at = (scale[:, None] * bounds[None, :]).astype(dtype)[None, None]  # (1, 1, L, n + 1)
    c = cut_cumulative(at, n, lambda j: knots[j], lambda j: table[:, :, j[0, 0]])  # (M, 3, L, n + 1)
    w_levels = xp.moveaxis(xp.diff(c, axis=-1)[..., order], 2, 0)  # (L, M, 3, n)
    w_levels = xp.where(fits[:, None, None, None], w_table[None], w_levels)  # untouched levels: their own weights
    return scale.astype(dtype), w_levels


def renormalised(w_cut, w_full_total):
    """The cut kernel's weights scaled to the full kernel's total (``border="renormalise"``: the part beyond the frame
    counts as the part inside); a kernel with nothing left keeps its (zero) weights."""
    total = jnp.sum(w_cut, axis=-1, keepdims=True)
    ok = total > 0
    return w_cut * jnp.where(ok, w_full_total / jnp.where(ok, total, 1.0), 1.0)
