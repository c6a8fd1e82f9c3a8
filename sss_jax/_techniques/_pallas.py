"""Pallas kernels for the whole-frame passes: one kernel per pass, the tap/sample loop inside it.

Each program takes a block of ``block`` consecutive pixels (row-major, the frame flattened and padded to whole
blocks), keeps its accumulators in registers through the loop, and gathers what each tap or sample reads from the
whole source planes (one gather per plane and pixel read: R, G, B and depth, validity being depth > 0). A block whose
pixels all skip the pass copies its input and runs no loop: the cost follows the scene on the device, no host count.
The per-tap and per-sample arithmetic is the XLA formulation's own (``_separable_gpu.pass_result``,
``_burley_gpu.sample_term``), so the two cannot drift apart.

On a GPU the kernels lower through Triton (1D blocks of a power-of-two size, gathers through pointers); elsewhere
they run with ``interpret=True`` (slow; what the tests use on CPU). ``pallas_call`` has no automatic derivative:
each pass is a ``custom_jvp`` whose tangent is the XLA formulation's (the same function, so the derivative is that
of the forward result), in forward mode (``jacfwd``, a Levenberg-Marquardt fit's linearisation) and, transposed, in
reverse mode.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jaxtyping import Array, ArrayLike

from .._materials import BurleyMaterial
from .._scene import Buffers, Camera
from ._burley_gpu import frame_pixels, frame_result, frames_mean, needs_truncation_on_device
from ._burley_spec import fetch_planes, frame_rotation, xla_fetch
from ._common import _finish
from ._separable_gpu import gather_pass, needs_cut, pass_result, pass_tables

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


def _separable_forward(e, z, reach_px, scale, skip, rows, w_table, unit_offsets, cut_table, axis, follow_surface,
                       interpolation, border, origin_along, frame_length, truncate, block):
    _, h, w = e.shape
    n_pix, n_taps = h * w, unit_offsets.shape[0]
    total = -(-n_pix // block) * block
    length = w if axis == 2 else h
    flat = lambda a, fill=0: _padded(a.reshape(n_pix), total, fill)
    sources = [flat(e[0]), flat(e[1]), flat(e[2]), flat(z)]
    per_pixel = [flat(e[0]), flat(e[1]), flat(e[2]), flat(z), flat(reach_px), flat(scale),
                 flat(skip.astype(jnp.int32), 1), flat(rows.astype(jnp.int32))]
    table_names = ("unit", "w", "wsum", "cell_lo", "cell_hi", "knots", "cut")
    tables = pass_tables(w_table, unit_offsets, 1, cut_table)  # one tap per step of the kernel's loop
    kw = dict(taps=n_taps, length=length, origin_along=origin_along, frame_length=frame_length,
              leaves=border == "leaves", truncate=truncate, one_row=w_table.shape[0] == 1,
              follow_surface=follow_surface, interpolation=interpolation, taps_per_step=1)

    def kernel(s0, s1, s2, sz, c0, c1, c2, cz, reach_ref, scale_ref, skip_ref, rows_ref, *refs):
        table_refs, outs = dict(zip(table_names, refs[:len(table_names)])), refs[len(table_names):]
        p = pl.program_id(0) * block + jax.lax.broadcasted_iota(jnp.int32, (block,), 0)
        centre = [c0[...], c1[...], c2[...]]
        skip_b = skip_ref[...] != 0

        def run():
            along = p % w if axis == 2 else p // w
            line = p - along if axis == 2 else p % w  # index of the pixel at position 0 of each pixel's line
            stride = 1 if axis == 2 else w

            def fetch(q):
                idx = jnp.clip(line + q * stride, 0, total - 1)
                return [s0[idx], s1[idx], s2[idx], sz[idx]]

            # the spec's pass: the XLA gather's own function, run on this block's pixels
            acc = pass_result(centre, cz[...], reach_ref[...], scale_ref[...], rows_ref[...], along, fetch,
                              table_refs, **kw)
            return tuple(jnp.where(skip_b, centre[c], acc[c]) for c in range(3))

        out = jax.lax.cond(jnp.all(skip_b), lambda: tuple(centre), run)
        for ref, o in zip(outs, out):
            ref[...] = o

    out = _call(kernel, sources, per_pixel, [tables[k] for k in table_names], 3, total, block, e.dtype)
    return jnp.stack([o[:n_pix].reshape(h, w) for o in out])


_SEPARABLE_STATIC = (9, 10, 11, 12, 13, 14, 15)


@functools.partial(jax.custom_jvp, nondiff_argnums=_SEPARABLE_STATIC)
def _separable_pass(e, z, reach_px, scale, skip, rows, w_table, unit_offsets, cut_table, axis, follow_surface,
                    interpolation, border, origin_along, frame_length, block):
    run = lambda truncate: _separable_forward(e, z, reach_px, scale, skip, rows, w_table, unit_offsets, cut_table,
                                              axis, follow_surface, interpolation, border, origin_along,
                                              frame_length, truncate, block)
    if cut_table is None:  # as gather_pass: the caller knows no kernel reaches past the frame
        return run(False)
    wide = needs_cut(reach_px, skip, unit_offsets.shape[0], frame_length)  # as gather_pass decides it
    return jax.lax.cond(wide, lambda: run(True), lambda: run(False))


@_separable_pass.defjvp
def _separable_jvp(axis, follow_surface, interpolation, border, origin_along, frame_length, block, primals,
                   tangents):
    """The pass's value from the kernel, its derivative the XLA gather formulation's (the same sums): a JVP rule,
    so forward mode (``jacfwd``, Levenberg-Marquardt's linearisation) runs and reverse mode transposes it."""
    out = _separable_pass(*primals, axis, follow_surface, interpolation, border, origin_along, frame_length, block)
    xla = functools.partial(gather_pass, axis=axis, follow_surface=follow_surface, interpolation=interpolation,
                            border=border, origin_along=origin_along, frame_length=frame_length)
    return out, jax.jvp(xla, primals, tangents)[1]


def separable_pass_pallas(e: Array, z: Array, reach_px: Array, scale: Array, skip: Array, rows: Array,
                          w_table: Array, unit_offsets: Array, cut_table: Array | None = None, *, axis: int,
                          follow_surface: bool, interpolation: str, border: str = "renormalise", origin_along: int = 0,
                          frame_length: int | None = None, block: int = BLOCK) -> Array:
    """``_separable_gpu.gather_pass`` as one Pallas kernel (same arguments, same result to rounding)."""
    if axis not in (1, 2):
        raise ValueError(f"axis must be 1 (vertical) or 2 (horizontal), got {axis!r}")
    length = e.shape[axis]
    return _separable_pass(e, z, reach_px, scale, skip, rows, w_table, unit_offsets, cut_table, axis,
                           bool(follow_surface),
                           interpolation, border, int(origin_along),
                           int(length if frame_length is None else frame_length), int(block))


_PIXEL_KEYS = ("row", "col", "z", "dmax", "ppm", "inside", "cos_phi", "sin_phi")


def _burley_forward(pix, active, buffer_shape, origin, frame_shape, samples, mm_per_unit, interpolation,
                    weight_channels, truncate, border, block):
    h, w = buffer_shape
    n_pix = h * w
    total = -(-n_pix // block) * block
    dtype = pix["z"].dtype
    flat = lambda a, fill=0: _padded(a, total, fill)
    sources = fetch_planes(pix, buffer_shape)  # whole (padded) planes: every sample's fetch lies in them
    wc = weight_channels
    per_pixel = ([flat(pix[k]) for k in _PIXEL_KEYS] + [flat(pix["e"][c]) for c in range(3)]
                 + [flat(pix["decay"][c]) for c in range(wc)]
                 + [flat(pix["ok_d"][c].astype(jnp.int32)) for c in range(wc)]
                 + [flat(active.astype(jnp.int32))])
    small = [jnp.reshape(mm_per_unit, (1,)).astype(dtype)]
    n_keys = len(_PIXEL_KEYS)

    def kernel(*refs):
        s0, s1, s2, sz = refs[:4]
        blocks = refs[4:4 + len(per_pixel)]
        mpu_ref = refs[4 + len(per_pixel)]
        outs = refs[5 + len(per_pixel):]
        centre = [blocks[n_keys + c][...] for c in range(3)]
        active_b = blocks[-1][...] != 0

        def run():
            pixel = {k: blocks[j][...] for j, k in enumerate(_PIXEL_KEYS)}
            pixel["e"] = centre
            pixel["decay"] = [blocks[n_keys + 3 + c][...] for c in range(wc)]
            pixel["ok_d"] = [blocks[n_keys + 3 + wc + c][...] != 0 for c in range(wc)]

            def fetch(idx):
                return [s0[idx], s1[idx], s2[idx], sz[idx]]

            # the spec's frame: the XLA layouts' own function, run on this block's pixels
            return tuple(frame_result(pixel, fetch, pixel["cos_phi"], pixel["sin_phi"], samples=samples,
                                      truncate=truncate, border=border, weight_channels=wc, buffer_shape=(h, w),
                                      origin=origin, frame_shape=frame_shape, mm_per_unit=mpu_ref[0],
                                      interpolation=interpolation))

        out = jax.lax.cond(jnp.any(active_b), run, lambda: tuple(centre))
        for ref, o in zip(outs, out):
            ref[...] = o

    out = _call(kernel, sources, per_pixel, small, 3, total, block, dtype)
    return [o[:n_pix] for o in out]


_BURLEY_STATIC = (2, 3, 4, 5, 7, 8, 9, 10, 11)


@functools.partial(jax.custom_jvp, nondiff_argnums=_BURLEY_STATIC)
def _burley_pass(pix, active, buffer_shape, origin, frame_shape, samples, mm_per_unit, interpolation,
                 weight_channels, truncate, border, block):
    return _burley_forward(pix, active, buffer_shape, origin, frame_shape, samples, mm_per_unit, interpolation,
                           weight_channels, truncate, border, block)


@_burley_pass.defjvp
def _burley_jvp(buffer_shape, origin, frame_shape, samples, interpolation, weight_channels, truncate, border, block,
                primals, tangents):
    """The frame's value from the kernel, its derivative the gather layout's (the same sums): a JVP rule, so
    forward mode (``jacfwd``, Levenberg-Marquardt's linearisation) runs and reverse mode transposes it."""
    pix, active, mm_per_unit = primals
    out = _burley_forward(pix, active, buffer_shape, origin, frame_shape, samples, mm_per_unit, interpolation,
                          weight_channels, truncate, border, block)

    def xla(pix, active, mm_per_unit):  # the gather layout of the same frame
        fetch = xla_fetch(fetch_planes(pix, buffer_shape), interpolation)
        return frame_result(pix, fetch, pix["cos_phi"], pix["sin_phi"], samples=samples, truncate=truncate,
                            border=border, weight_channels=weight_channels, buffer_shape=buffer_shape, origin=origin,
                            frame_shape=frame_shape, mm_per_unit=mm_per_unit, interpolation=interpolation)

    return out, jax.jvp(xla, primals, tangents)[1]


def burley_pallas_frame(pix: dict, active: Array, *, buffer_shape: tuple[int, int], origin: tuple[int, int],
                        frame_shape: tuple[int, int], samples: int, mm_per_unit: Array, interpolation: str,
                        weight_channels: int, truncate: bool, border: str, block: int = BLOCK) -> list[Array]:
    """``_burley_gpu.frame_result`` over the whole buffer as one Pallas kernel (``pix`` carries the frame's
    ``cos_phi``/``sin_phi`` planes); ``active (N,)``: blocks with no active pixel skip the sample loop."""
    pix = {k: v for k, v in pix.items() if k not in ("frow", "fcol")}
    return _burley_pass(pix, active, tuple(buffer_shape), tuple(origin), tuple(frame_shape), int(samples),
                        mm_per_unit, interpolation, int(weight_channels), bool(truncate), border, int(block))


@eqx.filter_jit
def burley_pallas_impl(buffers: Buffers, material: BurleyMaterial, camera: Camera, samples: int, albedo_mode: str,
                       interpolation: str, min_footprint_px: float, weight_channels: int = 3,
                       pattern: str = "rotated", frames: int = 1, seed: ArrayLike = 0, border: str = "leaves",
                       origin: tuple[int, int] = (0, 0), frame_shape: tuple[int, int] | None = None,
                       block: int = BLOCK) -> Array:
    """``burley``'s "pallas" formulation: the gather layout's frame as Pallas blocks, decided on the device."""
    h, w = buffers.depth.shape
    dtype, prep, frame_shape, pix, active = frame_pixels(buffers, material, camera, albedo_mode, min_footprint_px,
                                                         weight_channels, origin, frame_shape)
    seed = jnp.asarray(seed).astype(jnp.uint32)
    kw = dict(buffer_shape=(h, w), origin=tuple(origin), frame_shape=frame_shape, samples=samples,
              mm_per_unit=camera.mm_per_unit.astype(dtype), interpolation=interpolation,
              weight_channels=weight_channels, border=border, block=block)
    flat_active = active.reshape(-1)

    def one_frame(k):
        cos_phi, sin_phi = frame_rotation(pix, k, seed, pattern=pattern)
        planes = dict(pix, cos_phi=cos_phi, sin_phi=sin_phi)
        return jax.lax.cond(needs_truncation_on_device(pix, active),
                            lambda: tuple(burley_pallas_frame(planes, flat_active, truncate=True, **kw)),
                            lambda: tuple(burley_pallas_frame(planes, flat_active, truncate=False, **kw)))

    out = frames_mean(one_frame, frames, jnp.zeros_like(pix["z"]))
    scattered = jnp.stack(out, axis=-1).reshape(h, w, 3)
    scattered = jnp.where(active[..., None], scattered, prep.irradiance)
    return _finish(buffers, prep, scattered)
