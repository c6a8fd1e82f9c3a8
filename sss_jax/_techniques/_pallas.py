"""Pallas kernels for the whole-frame passes: one kernel per pass, the tap/sample loop inside it.

Each program takes a block of ``block`` consecutive pixels (row-major, the frame flattened and padded to whole
blocks), keeps its accumulators in registers through the loop, and gathers what each tap or sample reads from the
whole source planes (one gather per plane and pixel read: R, G, B and depth, validity being depth > 0). A block whose
pixels all skip the pass copies its input and runs no loop: the cost follows the scene on the device, no host count.
The per-tap and per-sample arithmetic is the XLA formulation's own (``_separable_gpu.tap_term``,
``_burley_gpu.sample_term``), so the two cannot drift apart.

On a GPU the kernels lower through Triton (1D blocks of a power-of-two size, gathers through pointers); elsewhere
they run with ``interpret=True`` (slow; what the tests use on CPU). ``pallas_call`` has no automatic derivative:
each pass is a ``custom_vjp`` whose backward pass is the XLA formulation's (the same function, so the gradient is
that of the forward result).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jaxtyping import Array

from ._burley_gpu import gather_burley, normalise, sample_term
from ._separable_gpu import gather_pass, tap_term

# Pixels per program: a power of two (Triton's block shapes must be), large enough to fill a GPU's warps.
BLOCK = 256


def _interpret() -> bool:
    return jax.default_backend() != "gpu"


def _padded(a: Array, total: int, fill=0) -> Array:
    return jnp.pad(a, (0, total - a.shape[0]), constant_values=fill)


def _call(kernel, planes_full: list[Array], planes_block: list[Array], small: list[Array], n_out: int, total: int,
          block: int, dtype):
    """``pallas_call`` over ``total // block`` programs: whole arrays for ``planes_full`` and ``small``, one block of
    each of ``planes_block`` per program, ``n_out`` planes out (one block each)."""
    whole = lambda a: pl.BlockSpec(a.shape, lambda i: (0,) * a.ndim)
    blocked = pl.BlockSpec((block,), lambda i: (i,))
    return pl.pallas_call(
        kernel,
        out_shape=tuple(jax.ShapeDtypeStruct((total,), dtype) for _ in range(n_out)),
        grid=(total // block,),
        in_specs=[whole(a) for a in planes_full] + [blocked] * len(planes_block) + [whole(a) for a in small],
        out_specs=tuple(blocked for _ in range(n_out)),
        interpret=_interpret(),
    )(*planes_full, *planes_block, *small)


def _separable_forward(e, z, reach_px, scale, skip, rows, w_table, unit_offsets, axis, follow_surface,
                       interpolation, block):
    _, h, w = e.shape
    n_pix, n_taps = h * w, unit_offsets.shape[0]
    total = -(-n_pix // block) * block
    length = w if axis == 2 else h
    limit = length + 1.0
    flat = lambda a, fill=0: _padded(a.reshape(n_pix), total, fill)
    sources = [flat(e[0]), flat(e[1]), flat(e[2]), flat(z)]
    per_pixel = [flat(e[0]), flat(e[1]), flat(e[2]), flat(z), flat(reach_px), flat(scale),
                 flat(skip.astype(jnp.int32), 1), flat(rows.astype(jnp.int32))]
    w_flat = w_table.reshape(-1)  # (M * 3 * n): row m, channel c, tap i at (3 m + c) n + i
    w_sum = jnp.sum(w_table, axis=-1).reshape(-1)  # (M * 3)

    def kernel(s0, s1, s2, sz, c0, c1, c2, cz, reach_ref, scale_ref, skip_ref, rows_ref, unit_ref, w_ref, wsum_ref,
               o0, o1, o2):
        p = pl.program_id(0) * block + jax.lax.broadcasted_iota(jnp.int32, (block,), 0)
        centre = [c0[...], c1[...], c2[...]]
        skip_b = skip_ref[...] != 0

        def run():
            z_b, reach, sc, rows_b = cz[...], reach_ref[...], scale_ref[...], rows_ref[...]
            along = p % w if axis == 2 else p // w
            line = p - along if axis == 2 else p % w  # index of the pixel at position 0 of each pixel's line
            stride = 1 if axis == 2 else w

            def fetch(q):
                idx = jnp.clip(line + q * stride, 0, total - 1)
                return [s0[idx], s1[idx], s2[idx], sz[idx]]

            def tap(i, acc):
                off = jnp.clip(unit_ref[i] * reach, -limit, limit)
                term = tap_term(off, along, length, fetch, centre, z_b, sc, follow_surface=follow_surface,
                                interpolation=interpolation)
                return tuple(a + w_ref[(rows_b * 3 + c) * n_taps + i] * t for c, (a, t) in enumerate(zip(acc, term)))

            acc = tuple(centre[c] * wsum_ref[rows_b * 3 + c] for c in range(3))
            acc = jax.lax.fori_loop(0, n_taps, tap, acc)
            return tuple(jnp.where(skip_b, centre[c], acc[c]) for c in range(3))

        out = jax.lax.cond(jnp.all(skip_b), lambda: tuple(centre), run)
        o0[...], o1[...], o2[...] = out

    out = _call(kernel, sources, per_pixel, [unit_offsets, w_flat, w_sum], 3, total, block, e.dtype)
    return jnp.stack([o[:n_pix].reshape(h, w) for o in out])


@functools.partial(jax.custom_vjp, nondiff_argnums=(8, 9, 10, 11))
def _separable_pass(e, z, reach_px, scale, skip, rows, w_table, unit_offsets, axis, follow_surface, interpolation,
                    block):
    return _separable_forward(e, z, reach_px, scale, skip, rows, w_table, unit_offsets, axis, follow_surface,
                              interpolation, block)


def _separable_fwd(e, z, reach_px, scale, skip, rows, w_table, unit_offsets, axis, follow_surface, interpolation,
                   block):
    out = _separable_forward(e, z, reach_px, scale, skip, rows, w_table, unit_offsets, axis, follow_surface,
                             interpolation, block)
    return out, (e, z, reach_px, scale, skip, rows, w_table, unit_offsets)


def _separable_bwd(axis, follow_surface, interpolation, block, residuals, cotangent):
    xla = functools.partial(gather_pass, axis=axis, follow_surface=follow_surface, interpolation=interpolation)
    return jax.vjp(xla, *residuals)[1](cotangent)


_separable_pass.defvjp(_separable_fwd, _separable_bwd)


def separable_pass_pallas(e: Array, z: Array, reach_px: Array, scale: Array, skip: Array, rows: Array,
                          w_table: Array, unit_offsets: Array, *, axis: int, follow_surface: bool, interpolation: str,
                          block: int = BLOCK) -> Array:
    """``_separable_gpu.gather_pass`` as one Pallas kernel (same arguments, same result to rounding)."""
    if axis not in (1, 2):
        raise ValueError(f"axis must be 1 (vertical) or 2 (horizontal), got {axis!r}")
    return _separable_pass(e, z, reach_px, scale, skip, rows, w_table, unit_offsets, axis, bool(follow_surface),
                           interpolation, int(block))


def _inverse_ccdf_unit(v: Array) -> Array:
    """``burley_inverse_ccdf(v, 1)`` from exp, log and sqrt only (what every kernel backend lowers):
    ``asinh(x) = log(x + sqrt(x^2 + 1))`` and ``2 sinh(a) = exp(a) - exp(-a)``; ``v`` lies in [1/(2S), 1] here,
    where the subtraction loses at most a few bits."""
    v = jnp.clip(v, jnp.finfo(v.dtype).tiny * 2.0**24, 1.0)
    a = jnp.log(2 * v + jnp.sqrt(4 * v * v + 1)) / 3
    return -3 * jnp.log(jnp.minimum(jnp.exp(a) - jnp.exp(-a), 1.0))


_PIXEL_KEYS = ("row", "col", "z", "dmax", "ppm", "inside", "phi")


def _burley_forward(pix, active, sample_u, sample_theta, height, width, mm_per_unit, interpolation,
                    weight_channels, block):
    n_pix = height * width
    total = -(-n_pix // block) * block
    dtype = pix["z"].dtype
    flat = lambda a, fill=0: _padded(a, total, fill)
    sources = [flat(pix["e"][c]) for c in range(3)] + [flat(pix["z"])]
    per_pixel = ([flat(pix[k]) for k in _PIXEL_KEYS] + [flat(pix["e"][c]) for c in range(3)]
                 + [flat(pix["inv_d"][c]) for c in range(weight_channels)]
                 + [flat(pix["ok_d"][c].astype(jnp.int32)) for c in range(weight_channels)]
                 + [flat(active.astype(jnp.int32))])
    small = [sample_u, sample_theta, jnp.reshape(mm_per_unit, (1,)).astype(dtype)]
    n_keys, wc = len(_PIXEL_KEYS), weight_channels

    def kernel(*refs):
        s0, s1, s2, sz = refs[:4]
        blocks = refs[4:4 + len(per_pixel)]
        u_ref, theta_ref, mpu_ref = refs[4 + len(per_pixel):7 + len(per_pixel)]
        outs = refs[7 + len(per_pixel):]
        centre = [blocks[n_keys + c][...] for c in range(3)]
        active_b = blocks[-1][...] != 0

        def run():
            pixel = {k: blocks[j][...] for j, k in enumerate(_PIXEL_KEYS)}
            pixel["e"] = centre
            pixel["inv_d"] = [blocks[n_keys + 3 + c][...] for c in range(wc)]
            pixel["ok_d"] = [blocks[n_keys + 3 + wc + c][...] != 0 for c in range(wc)]
            mpu = mpu_ref[0]

            def fetch(idx):
                idx = jnp.clip(idx, 0, total - 1)
                return [s0[idx], s1[idx], s2[idx], sz[idx]]

            def body(i, acc):
                num, den = sample_term(u_ref[i], theta_ref[i], pixel, fetch, height=height, width=width,
                                       mm_per_unit=mpu, interpolation=interpolation, inverse_ccdf=_inverse_ccdf_unit,
                                       weight_channels=wc)
                return tuple(a + b for a, b in zip(acc[0], num)), tuple(a + b for a, b in zip(acc[1], den))

            zeros = jnp.zeros((block,), dtype)
            num, den = jax.lax.fori_loop(0, sample_u.shape[0], body, ((zeros,) * 3, (zeros,) * wc))
            return tuple(normalise(list(num), list(den), centre))

        out = jax.lax.cond(jnp.any(active_b), run, lambda: tuple(centre))
        for ref, o in zip(outs, out):
            ref[...] = o

    out = _call(kernel, sources, per_pixel, small, 3, total, block, dtype)
    return [o[:n_pix] for o in out]


@functools.partial(jax.custom_vjp, nondiff_argnums=(4, 5, 7, 8, 9))
def _burley_pass(pix, active, sample_u, sample_theta, height, width, mm_per_unit, interpolation, weight_channels,
                 block):
    return _burley_forward(pix, active, sample_u, sample_theta, height, width, mm_per_unit, interpolation,
                           weight_channels, block)


def _burley_fwd(pix, active, sample_u, sample_theta, height, width, mm_per_unit, interpolation, weight_channels,
                block):
    out = _burley_forward(pix, active, sample_u, sample_theta, height, width, mm_per_unit, interpolation,
                          weight_channels, block)
    return out, (pix, active, sample_u, sample_theta, mm_per_unit)


def _burley_bwd(height, width, interpolation, weight_channels, block, residuals, cotangent):
    pix, active, sample_u, sample_theta, mm_per_unit = residuals

    def xla(pix, active, sample_u, sample_theta, mm_per_unit):
        return gather_burley(pix, sample_u, sample_theta, height=height, width=width, mm_per_unit=mm_per_unit,
                             interpolation=interpolation, weight_channels=weight_channels)

    return jax.vjp(xla, *residuals)[1](cotangent)


_burley_pass.defvjp(_burley_fwd, _burley_bwd)


def burley_pallas(pix: dict, active: Array, sample_u: Array, sample_theta: Array, *, height: int, width: int,
                  mm_per_unit: Array, interpolation: str, weight_channels: int, block: int = BLOCK) -> list[Array]:
    """``_burley_gpu.gather_burley`` as one Pallas kernel; ``active (N,)``: blocks with no active pixel skip the
    sample loop (their pixels are masked by the caller anyway)."""
    return _burley_pass(pix, active, sample_u, sample_theta, height, width, mm_per_unit, interpolation,
                        weight_channels, int(block))
