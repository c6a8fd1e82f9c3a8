"""``burley``'s XLA formulations: the spec's sample loop (``_burley_spec.sample_term``) over two layouts of pixels.

- ``"compacted"``: the active pixels, counted on the host and compacted into a buffer of the next quarter-octave
  size (``_burley.compaction_capacity``: one compilation per size bucket), computed and scattered back; the host
  also decides whether the samples need the truncated inverse CDF and whether the material's channels share one
  kernel. Fastest on a CPU, where the
  pixels skipped pay more than the host round trip.
- ``"gather"``: every pixel of the frame in one fused loop over the samples, masked at the end, decided on the
  device (no host read: the truncation is a ``lax.cond`` on the frame's widest profile). What a GPU runs; under
  ``jit``/``vmap`` the compacted layout becomes this one (nothing can be counted there).

The spiral's rotation (per pixel and frame, from ``seed``), ``frames`` (the mean of K rotated frames), the border
rule and the tile's place in its frame are the spec's, the same in every layout.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._materials import BurleyMaterial
from .._scene import Buffers, Camera
from ._burley_spec import (
    FETCH_PAD,
    TRUNCATION_ENERGY,
    Origin,
    fetch_planes,
    frame_rotation,
    leaving_energy,
    normalise,
    pixel_planes,
    pixel_planes_at,
    sample_fetch,
    sample_place,
    sample_weights,
    weight_offset,
    xla_fetch,
)
from ._common import (
    _as_seed,
    _finish,
    _material_rows,
    _prepare,
    _work_dtype,
    padded_indices,
)


def frame_result(pix: dict, fetch, cos_phi: Array, sin_phi: Array, *, samples: int, truncate: bool, border: str,
                 weight_channels: int, buffer_shape: tuple[int, int], origin: Origin,
                 frame_shape: tuple[int, int], mm_per_unit: Array, interpolation: str, chunks: int = 1,
                 shift_weights: bool = True) -> list[Array]:
    """One frame's scattered channels (3 planes over the layout's pixels), the spiral turned by ``cos_phi``,
    ``sin_phi``: ``samples`` samples, each channel normalised by its weights (plus, with truncated sampling and
    ``border="leaves"``, the energy beyond the frame's diagonal, which leaves).

    The loop computes each sample's place one iteration ahead and carries it: XLA's CPU backend materialises a
    loop-carried value once, where a value computed and used in one iteration is recomputed inside every fusion that
    reads it (the place feeds the gathers, the kernels and the sums of every corner and channel). ``chunks`` > 1 runs
    the sample loop over that many chunks of the pixels, one after another (``lax.map``: one compiled loop), each a
    multiple of ``CHUNK_ALIGN`` pixels (the last padded with pixels of no surface, cut off after), so that a chunk's
    planes, places and weights stay in the caches through its samples (``cpu_chunks``). Same arithmetic either way.
    ``shift_weights``: each channel's weights scaled by its nearest sample's (``weight_offset``: needed where a
    channel is far narrower than the widest; the host leaves it out where no material needs it, ``needs_weight_shift``:
    it reads two planes more per fetch, ~5% of the CPU pass)."""
    shift = weight_offset(pix, samples, truncate=truncate, weight_channels=weight_channels) if shift_weights else {}
    planes = dict(pix, cos_phi=cos_phi, sin_phi=sin_phi, **shift)
    n = pix["z"].shape[0]

    def place(piece, i):
        return sample_place(i, samples, piece["cos_phi"], piece["sin_phi"], piece, buffer_shape=buffer_shape,
                            origin=origin, frame_shape=frame_shape, interpolation=interpolation, truncate=truncate,
                            border=border)

    def sums(piece: dict) -> tuple[Array, Array]:
        """Every sample's weighted sums over one chunk's pixels: numerator (3, m), denominator (weight_channels, m)."""
        def body(i, acc):
            num_acc, den_acc, here = acc
            ahead = place(piece, jnp.minimum(i + 1, samples - 1))
            here = sample_fetch(here, fetch, buffer_shape=buffer_shape, interpolation=interpolation)
            num, den = sample_weights(here, piece, mm_per_unit=mm_per_unit, interpolation=interpolation,
                                      weight_channels=weight_channels, border=border)
            return num_acc + num, den_acc + den, ahead

        zeros = lambda count: jnp.zeros((count, *piece["z"].shape), piece["z"].dtype)
        num, den, _ = jax.lax.fori_loop(0, samples, body, (zeros(3), zeros(weight_channels), place(piece, 0)))
        return num, den

    if chunks <= 1:
        num, den = sums(planes)
    else:
        size = -(-n // chunks)
        size = -(-size // CHUNK_ALIGN) * CHUNK_ALIGN
        # the padding: zero planes, pixels of no surface (d = 0, so every weight 0), computed and cut off
        chunked = lambda a: jnp.pad(a, (0, size * chunks - n)).reshape(chunks, size)
        num, den = jax.lax.map(sums, jax.tree.map(chunked, planes))  # (chunks, 3, size), (chunks, wc, size)
        num, den = (jnp.moveaxis(a, 1, 0).reshape(a.shape[1], chunks * size)[:, :n] for a in (num, den))
    num, den = list(num), list(den)
    if truncate and border == "leaves":
        leave = leaving_energy(planes, frame_shape)
        den = [den[c] + samples * leave[c] for c in range(weight_channels)]
    return normalise(num, den, pix["e"])


# On a CPU backend the sample loop runs over chunks of at most CHUNK_PIXELS pixels, one after another, each a multiple
# of CHUNK_ALIGN pixels (odd sizes leave the vectorised loops a scalar tail: thirds of the demo frame's 57344 slots
# ran 2x slower). It ran before as one loop over two concurrent chains of halves of the pixels (one per core): the
# default call against that, both trees in one process, alternating (2026-12-03, 2 vCPUs of an AMD EPYC, 1 MB of L2
# a core, 32 MB of L3): full coverage at 640x360 (230400 pixels, 8 chunks) 0.46 of the time (148 -> 68 ms), the demo
# frame at 1920x1080 0.54 (546 -> 297 ms), the demo frame at 640x360 (57344 slots: 2 chunks, the size of the chains
# before) 0.97-1.02; the same slots as 1 chunk 1.16 of 2 chunks', full coverage as 16 chunks within 7% of 8. So the
# size of a chunk is what counts: its planes, places and weights (~100-250 bytes a pixel) stay in the caches through
# its samples; two concurrent chains gained nothing here over one after the other (XLA on one thread ran the whole
# default call ~5% faster than on two).
CHUNK_PIXELS = 32768
CHUNK_ALIGN = 512


def cpu_chunks(pixels: int) -> int:
    """How many chunks ``frame_result`` runs ``pixels`` in: on a CPU backend enough that none holds more than
    ``CHUNK_PIXELS``, else 1 (a GPU keeps every pixel in one loop: its fusions parallelise over them)."""
    if jax.default_backend() != "cpu":
        return 1
    return max(1, -(-int(pixels) // CHUNK_PIXELS))


def frames_mean(one_frame, frames: int, zeros: Array) -> list[Array]:
    """``one_frame(k)`` for k = 0, or the mean over ``frames`` frames (each with its own rotations: converged TAA)."""
    if frames == 1:
        return list(one_frame(0))
    total = jax.lax.fori_loop(0, frames, lambda k, acc: tuple(a + b for a, b in zip(acc, one_frame(k))),
                              (zeros,) * 3)
    return [t / frames for t in total]


def sample_loop(pix: dict, fetch, *, frames: int, seed: ArrayLike, pattern: str, rotation=None, **kw) -> list[Array]:
    """The scattered channels over the layout's pixels, ``frames`` frames averaged (``frame_result``).
    ``rotation``: frame 0's ``frame_rotation``, where computed already (one frame only)."""
    if rotation is not None and frames != 1:
        raise ValueError(f"a given rotation serves one frame, not frames={frames}")
    turn = lambda k: rotation if rotation is not None else frame_rotation(pix, k, seed, pattern=pattern)
    return frames_mean(lambda k: frame_result(pix, fetch, *turn(k), **kw), frames, jnp.zeros_like(pix["z"]))


def layout_result(pix: dict, fetch, active: Array, truncate: bool | None, **kw) -> list[Array]:
    """``sample_loop`` over a layout's pixels (``kw``: its options but ``chunks``, which follows the pixels' count),
    the truncation decided on the host (``truncate`` a bool) or on the device (``None``: a ``lax.cond`` on the widest
    profile among the ``active`` pixels)."""
    kw["chunks"] = cpu_chunks(pix["z"].shape[0])
    if truncate is None:
        return jax.lax.cond(needs_truncation_on_device(pix, active),
                            lambda: sample_loop(pix, fetch, truncate=True, **kw),
                            lambda: sample_loop(pix, fetch, truncate=False, **kw))
    return sample_loop(pix, fetch, truncate=truncate, **kw)


def frame_pixels(buffers: Buffers, material: BurleyMaterial, camera: Camera, albedo_mode: str,
                 min_footprint_px: float, weight_channels: int, origin: tuple[int, int],
                 frame_shape: tuple[int, int] | None):
    """What every formulation starts from: the work dtype, the prepared buffers (albedo split), the frame's shape
    (this buffer's where none is given) and the per-pixel planes with the active mask (``pixel_planes``)."""
    dtype = _work_dtype(buffers.irradiance.dtype)
    prep = _prepare(buffers, material.albedo, albedo_mode, dtype)
    frame_shape = tuple(buffers.depth.shape) if frame_shape is None else tuple(frame_shape)
    pix, active = pixel_planes(buffers, material, camera, prep, min_footprint_px=min_footprint_px,
                               weight_channels=weight_channels, dtype=dtype, origin=tuple(origin),
                               frame_shape=frame_shape)
    return dtype, prep, frame_shape, pix, active


def needs_truncation_on_device(pix: dict, active: Array) -> Array:
    """Whether any active pixel's widest profile has more than ``TRUNCATION_ENERGY`` beyond the frame's diagonal
    (``_burley_spec.needs_truncation``, decided on the device)."""
    return jnp.any(active.reshape(-1) & (1 - pix["inside"] > TRUNCATION_ENERGY))


def _burley_impl(buffers: Buffers, material: BurleyMaterial, camera: Camera, samples: int, albedo_mode: str,
                 interpolation: str, capacity: int | None, min_footprint_px: float, weight_channels: int = 3,
                 truncate: bool | None = None, pattern: str = "rotated", frames: int = 1, seed: ArrayLike = 0,
                 border: str = "leaves", origin: tuple[int, int] = (0, 0),
                 frame_shape: tuple[int, int] | None = None, active: Array | None = None,
                 planes: list[Array] | None = None, shift_weights: bool = True) -> Array:
    """The XLA formulations: ``capacity`` slots of compacted active pixels ("compacted", concrete inputs only: the
    host compacts), or ``None`` for every pixel ("gather", one jitted call); ``truncate`` decided on the host (a
    bool) or on the device (``None``). ``active`` (the active mask) and ``planes`` (``padded_planes``): where the
    host's count computed them already (``_burley._active_stats``); the compacted layout needs ``active``.
    ``shift_weights``: ``frame_result``'s."""
    frame_shape = tuple(buffers.depth.shape) if frame_shape is None else tuple(frame_shape)
    common = dict(pattern=pattern, frames=int(frames), seed=_as_seed(seed), border=border,
                  origin=tuple(origin), frame_shape=frame_shape, shift_weights=bool(shift_weights))
    if capacity is None:
        return _gather_impl(buffers, material, camera, samples, albedo_mode, interpolation, min_footprint_px,
                            weight_channels, truncate, planes=planes, **common)
    if active is None or planes is None:
        raise ValueError("the compacted layout takes the host count's active mask and padded planes "
                         "(_burley._burley_active_mask with albedo_mode)")
    h, w = buffers.depth.shape
    # host-side compaction (a CPU formulation's strategy)
    idx = jnp.asarray(padded_indices(np.asarray(jax.device_get(active)), capacity))
    if common["origin"] != (0, 0) or frame_shape != (h, w):
        # a tile's origin traced: the tiles of one shape and bucket share one program (static, each tile of a
        # 3840x2160 frame compiled its own: 15 compilations, ~11 s of a 19-s frame); the whole frame's program as before
        common["origin"] = jnp.asarray(common["origin"], jnp.int32)
    else:
        common["origin"] = None
    return _compacted_result(buffers, material, camera, idx, planes, samples, albedo_mode, interpolation,
                             min_footprint_px, weight_channels, truncate, **common)


def _compacted_planes(buffers: Buffers, material: BurleyMaterial, camera: Camera, idx: Array, planes: list[Array],
                      min_footprint_px: float, weight_channels: int, truncate: bool | None, *, pattern: str,
                      frames: int, seed: ArrayLike, border: str, origin: Origin, frame_shape: tuple[int, int]):
    """The compacted slots' per-pixel planes (``pixel_planes_at`` on the compacted pixels alone, not on the whole
    frame) and, for one frame, their rotation. ``idx``: each slot's pixel in the buffer (``H W`` in the unused slots,
    which hold pixels of no surface: they take part in nothing and are dropped when scattered back); a pixel's
    irradiance and depth are read from the padded planes, its place is its index. The planes the loop does not read
    (``truncate``, ``border``; the frame coordinates once the rotation is computed) are left out.

    Traced inside ``_compacted_result``: the sample loop takes the planes as its operands (the chunks' ``lax.map``
    or the loop's carry), which XLA materialises once. (A computation of its own before the chunks, it cost a
    dispatch and a round of the planes through memory: merged, side by side in one process, 2026-12-03, the two
    computations' work at 640x360 took 0.92-0.97 of the time, the whole default call 0.985.)"""
    dtype = _work_dtype(buffers.irradiance.dtype)
    h, w = buffers.depth.shape
    used = idx < h * w
    row, col = idx // w, idx % w
    # the slot's pixel in the padded planes; an unused slot reads the padding's corner (no surface)
    padded = jnp.where(used, (row + FETCH_PAD) * (w + 2 * FETCH_PAD) + col + FETCH_PAD, 0)
    *e, z = [jnp.take(plane.reshape(-1), padded, mode="clip") for plane in planes]
    rows = jnp.take(_material_rows(buffers, material.d_mm.shape[0]).reshape(-1), idx, mode="fill", fill_value=0)
    pix, _ = pixel_planes_at(material, camera, e=e, z=z, valid=used, rows=rows,
                             frow=jnp.where(used, row, 0) + origin[0], fcol=jnp.where(used, col, 0) + origin[1],
                             min_footprint_px=min_footprint_px, weight_channels=weight_channels, dtype=dtype,
                             frame_shape=frame_shape)
    rotation = None
    if frames == 1:
        rotation = frame_rotation(pix, 0, seed, pattern=pattern)
        del pix["frow"], pix["fcol"]  # the hash's inputs
    if truncate is False:
        del pix["inside"]  # the truncated radii's, and the device's truncation test's
    return pix, rotation


@functools.partial(jax.jit, static_argnames=("samples", "albedo_mode", "interpolation", "min_footprint_px",
                                             "weight_channels", "truncate", "pattern", "frames", "border",
                                             "frame_shape", "shift_weights"))
def _compacted_result(buffers: Buffers, material: BurleyMaterial, camera: Camera, idx: Array, planes: list[Array],
                      samples: int, albedo_mode: str, interpolation: str, min_footprint_px: float,
                      weight_channels: int, truncate: bool | None, *, pattern: str, frames: int, seed: ArrayLike,
                      border: str, origin: Array | None, frame_shape: tuple[int, int],
                      shift_weights: bool) -> Array:
    """The compacted layout's computation: the slots' planes (``_compacted_planes``), the sample loop over them,
    scattered back into the frame. ``origin``: a tile's (int32, traced), None for the whole frame."""
    origin = (0, 0) if origin is None else (origin[0], origin[1])
    h, w = buffers.depth.shape
    dtype = _work_dtype(buffers.irradiance.dtype)
    pix, rotation = _compacted_planes(buffers, material, camera, idx, planes, min_footprint_px, weight_channels,
                                      truncate, pattern=pattern, frames=frames, seed=seed, border=border,
                                      origin=origin, frame_shape=frame_shape)
    prep = _prepare(buffers, material.albedo, albedo_mode, dtype)
    fetch = xla_fetch([plane.reshape(-1) for plane in planes], interpolation)
    out = layout_result(pix, fetch, idx < h * w, truncate, samples=samples, frames=frames, seed=seed,
                        pattern=pattern, border=border, rotation=rotation, weight_channels=weight_channels,
                        buffer_shape=(h, w), origin=origin, frame_shape=frame_shape,
                        mm_per_unit=camera.mm_per_unit.astype(dtype), interpolation=interpolation,
                        shift_weights=shift_weights)
    # the active pixels are the slots': every other pixel is finished as its own (local) shading, and the slots'
    # finished values written over them (``_finish`` per pixel, so one pass over the frame instead of three)
    local = _finish(buffers, prep, prep.irradiance).reshape(h * w, 3)
    albedo = jnp.take(prep.albedo_out.reshape(h * w, 3), idx, axis=0, mode="fill", fill_value=0)
    slots = (albedo * jnp.stack(out, axis=-1)).astype(local.dtype)
    return local.at[idx].set(slots, mode="drop").reshape(h, w, 3)


@eqx.filter_jit
def _gather_impl(buffers: Buffers, material: BurleyMaterial, camera: Camera, samples: int, albedo_mode: str,
                 interpolation: str, min_footprint_px: float, weight_channels: int, truncate: bool | None, *,
                 pattern: str, frames: int, seed: ArrayLike, border: str, origin: tuple[int, int],
                 frame_shape: tuple[int, int], planes: list[Array] | None = None, shift_weights: bool = True) -> Array:
    """The gather layout: every pixel of the buffer, masked at the end, in one computation."""
    h, w = buffers.depth.shape
    dtype, prep, frame_shape, pix, active = frame_pixels(buffers, material, camera, albedo_mode, min_footprint_px,
                                                         weight_channels, origin, frame_shape)
    # the whole buffer's planes (the indices are in range), or the host count's, flattened
    planes = fetch_planes(pix, (h, w)) if planes is None else [plane.reshape(-1) for plane in planes]
    fetch = xla_fetch(planes, interpolation)
    out = layout_result(pix, fetch, active, truncate, samples=samples, frames=frames, seed=seed, pattern=pattern,
                        border=border, weight_channels=weight_channels, buffer_shape=(h, w), origin=origin,
                        frame_shape=frame_shape, mm_per_unit=camera.mm_per_unit.astype(dtype),
                        interpolation=interpolation, shift_weights=shift_weights)
    scattered = jnp.where(active[..., None], jnp.stack(out, axis=-1).reshape(h, w, 3), prep.irradiance)
    return _finish(buffers, prep, scattered)
