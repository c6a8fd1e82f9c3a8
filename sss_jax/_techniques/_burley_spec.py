"""``burley`` written once: the per-sample term, its constants, the inverse CDF, the rotation hash and the reach.

Every formulation of the pass (``_burley_gpu``: the compacted and the whole-frame gather layouts in XLA;
``_pallas``: blocks of pixels in a Pallas kernel) evaluates ``sample_term`` on its own layout of the per-pixel planes
``pixel_planes`` builds; they differ in which pixels they hold and how they loop, not in arithmetic.

Positions are frame coordinates: a buffer that is a tile of a larger frame states its top-left pixel in the frame
(``origin``) and the frame's size (``frame_shape``). The rotation hash, the frame border ("leaves": the part of a
fetch outside the frame counts as dark surface) and the truncation at the frame's diagonal follow the frame; a fetch
inside the frame but outside the buffer (a tile without enough halo) is dropped from the normalisation. A tile whose
halo covers the pass's reach (``burley_reach_px``) gives the untiled frame's pixels.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike

from .._checks import checked
from .._kernels import spiral_sample
from .._profiles import burley_cdf, burley_inverse_ccdf
from .._profiles import unit_radius_for_cdf as profile_unit_radius_for_cdf
from .._units import px_per_mm
from ._common import weighted_mean

# a tile's top-left pixel in the frame: Python ints, or int32 scalars traced (a compacted tile's: one program for
# the tiles of one shape)
Origin = tuple[int | Array, int | Array]


@functools.lru_cache(maxsize=256)
def unit_radius(ccdf: float) -> float:
    """Host side: the radius, in units of d, beyond which the fraction ``ccdf`` of a Burley profile's energy lies
    (``burley_inverse_ccdf(ccdf, 1)``), a Python float even where a trace surrounds the call (a JAX operation there
    would be staged, not evaluated)."""
    with jax.ensure_compile_time_eval(), jax.enable_x64(True):  # float64: a host constant, not the pass's dtype
        return float(np.asarray(burley_inverse_ccdf(np.float64(ccdf), np.float64(1.0))))


# radius holding 99% (95%) of a Burley profile's energy, in units of d: the footprint the skip and compaction test
# (the sampling check)
BURLEY_R99 = unit_radius(0.01)
BURLEY_R95 = unit_radius(0.05)

# Truncated sampling (each pixel's profile cut at the frame's diagonal, so huge d spreads over the frame instead of
# losing its samples) is taken where it changes the result: sampling the whole profile instead leaves the energy
# beyond the diagonal out of the normalisation, which moves a pixel by at most that energy, relative. Below 1e-4
# (a fortieth of an 8-bit step at full scale) every pixel shares the sample radii: one scalar inverse CDF per sample
# instead of a per-pixel inversion of the truncated CDF.
TRUNCATION_ENERGY = 1e-4


def burley_weight(r: Array, decay: Array, ok_d: Array, scale: Array, r0: Array | None = None,
                  tail: Array | None = None) -> Array:
    """``scale (e3 + e3^3) / r`` with ``e3 = exp(-r decay)``, ``decay = 1 / (3 d)`` (0 where d = 0): the Burley
    profile ``R(r) = (exp(-r/d) + exp(-r/3d)) / (8 pi d r)`` up to the factor ``8 pi d`` that cancels in each
    channel's normalisation, times ``scale``; one exponential per channel. ``d = 0`` (``ok_d`` false) gives 0, and so
    does r = 0 (``scale`` is 0 there: it carries 1/pdf, which is 0 at r = 0): no NaN, finite gradients.

    With ``r0`` and ``tail`` (``weight_offset``: a radius no sample of the pixel comes closer than, and
    ``exp(-2 r0 / (3 d))``, 0 where d = 0) the weight is scaled by ``exp(r0 / (3 d))``, one factor per pixel and
    channel that cancels in its normalisation: ``e3 = exp(-(r - r0) / (3 d)) <= 1`` and ``e3^3`` becomes
    ``tail e3^3``. The nearest sample's weight is then of order 1 whatever d_max / d is; unscaled, a channel far
    narrower than the widest (d = 0.001 mm beside d_max = 20 mm) weighs every sample exp(-700) or less, whose
    products with the irradiance XLA's CPU backend flushes to 0 as subnormals: the channel came out 0 where its
    weights did not, and the pass was not linear in the irradiance.

    Written for XLA's CPU fusion: the exponent is one product (``decay``, not ``-(r / d) / 3``: three operations an
    element), the factor d is left out (it cancels: one product and one plane less an element; the compacted pass
    at 640x360 in 0.96-1.00 of the time, medians of 41 alternating runs), ``ok_d`` masks the exponential, which
    keeps the simplifier from turning ``e3 * e3`` into a second exponential, and the divisor (with r > 0, so the mask
    has the weight's full shape), which keeps it from turning the division into a product with a reciprocal: the
    division is the weight's last operation, so the whole weight is one materialised value (XLA does not duplicate
    an expensive root) that the sums of the numerator and the denominator read, instead of each recomputing its
    arguments."""
    e3 = jnp.where(ok_d, jnp.exp(-(r * decay) if r0 is None else (r0 - r) * decay), 0.0)
    e3_squared = e3 * (e3 if tail is None else tail * e3)
    return scale * e3 * (1 + e3_squared) / jnp.where(ok_d & (r > 0), r, 1.0)


def weight_offset(pix: dict, samples: int, *, truncate: bool, weight_channels: int) -> dict:
    """The planes ``burley_weight`` scales each channel's weights by (``r0`` and its ``tail`` per weight channel),
    for the pixels of ``pix``; none for one (grey) weight channel, whose d is d_max (the weights stay of order 1).

    ``r0`` is sample 0's in-plane radius, the smallest of the pixel's samples (the stratified radii grow with the
    sample's index), computed as ``sample_place`` computes it (``sample_radius``: the same rounding): every fetch
    of the pixel lies at least that far (r3 >= r), so no scaled weight exceeds 1, and the nearest sample on the
    pixel's own surface weighs ~1 however narrow the channel. (A lower bound, ``2 u_0 d_max``, was ~10% short at 4
    samples: a channel 1e4 times narrower than the widest then weighed every sample exp(-83) or less, flushed to 0 in
    float32, and its pixels kept their own light where float64 scattered them.) Its gradient is stopped: the
    normalised result does not depend on it."""
    if weight_channels == 1:
        return {}
    u0, _ = spiral_sample(jnp.asarray(0).astype(pix["z"].dtype), samples)
    r0 = jax.lax.stop_gradient(sample_radius(u0, pix, truncate=truncate) * pix["dmax"])
    return {"r0": r0, "tail": [jnp.where(ok_d, jnp.exp(-2 * (r0 * decay)), 0.0)
                               for decay, ok_d in zip(pix["decay"], pix["ok_d"])]}


# ``needs_weight_shift``: below this exponent (a factor exp(-20) = 2e-9) the nearest sample's unshifted weight keeps
# ~1e-29 of float32's range for the irradiance it multiplies and the depth's fall-off
SHIFT_EXPONENT = 20.0


def needs_weight_shift(d_mm, samples: int, *, concrete: bool) -> bool:
    """Host side: whether ``frame_result`` must shift the weights (``weight_offset``) for materials ``d_mm``: where
    some channel's d is so far below its material's widest that its nearest sample, unshifted, weighs less than
    exp(-``SHIFT_EXPONENT``) (sample 0's radius in units of d_max at most ``unit_radius(1 - 1/(2 samples))``:
    truncation only draws it closer). True where d is not ``concrete`` (traced: it cannot be read)."""
    if not concrete:
        return True
    d = np.asarray(d_mm, np.float64).reshape(-1, 3)
    d_max = d.max(axis=1, keepdims=True)
    rho0 = unit_radius(1 - 0.5 / samples)
    exponent = np.where(d > 0, rho0 * d_max / (3 * np.where(d > 0, d, 1.0)), 0.0)
    return bool(exponent.max(initial=0.0) > SHIFT_EXPONENT)


def leaving_energy(pix: dict, frame_shape: tuple[int, int]) -> list[Array]:
    """Per weight channel, the energy of the pixel's profile beyond the frame's diagonal in the units of one
    sample's weight (samples drawn from the d_max profile truncated there, holding ``inside`` of its energy, weigh
    ``burley_weight``'s R_c 8 pi d_c / pdf, the pdf's 8 pi d_max^2 left out: a mass m counts as
    m / inside d_c / d_max^2), scaled as ``burley_weight`` scales the weights where ``pix`` holds ``r0``
    (``weight_offset``): Burley's CCDF ``(exp(-x) + 3 exp(-x/3)) / 4`` at ``x = r_clip / d`` times
    ``exp(r0 / (3 d))``, each exponent non-positive (``r0 < r_clip``)."""
    dmax = pix["dmax"]
    r_clip = clip_radius(pix["ppm"], frame_shape)
    ok_in = pix["inside"] > 0
    per_sample = jnp.where(ok_in, 1.0 / jnp.where(ok_in, pix["inside"], 1.0), 0.0)
    ok_dmax = dmax > 0
    inv_dmax = jnp.where(ok_dmax, 1.0 / jnp.where(ok_dmax, dmax, 1.0), 0.0)
    shift = pix.get("r0", 0.0)
    out = []
    for decay, ok_d in zip(pix["decay"], pix["ok_d"]):
        lift = shift * decay
        x3 = jnp.minimum(r_clip * decay, 1e30)  # r_clip / (3 d)
        ccdf = (jnp.exp(lift - 3 * x3) + 3 * jnp.exp(lift - x3)) / 4
        # m / inside d / d_max^2, d = 1 / (3 decay)
        out.append(jnp.where(ok_d, ccdf * per_sample * inv_dmax * inv_dmax / jnp.where(ok_d, 3 * decay, 1.0), 0.0))
    return out


def clip_radius(ppm: Array, frame_shape: tuple[int, int]) -> Array:
    """The frame's diagonal in mm at each pixel's scale (``ppm``: px per mm; 1e30 where it is 0): no sample beyond
    it can land in the frame, so the profile is sampled truncated there."""
    r_clip = jnp.where(ppm > 0, math.hypot(*frame_shape) / jnp.where(ppm > 0, ppm, 1.0), jnp.inf)
    return jnp.minimum(r_clip, 1e30)


def _hash_u32(x: Array) -> Array:
    """A 32-bit integer hash (Wellons' ``lowbias32``): consecutive inputs give unrelated outputs."""
    x = x.astype(jnp.uint32)
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * jnp.uint32(0x846CA68B)
    return x ^ (x >> 16)


def _rotation_turn(rows: Array, cols: Array, frame: ArrayLike, seed: ArrayLike, *, per_pixel: bool = True) -> Array:
    """``spiral_rotation``'s angle as an integer: the hash's top 24 bits, in units of 2^-24 of a turn (uint32)."""
    frame = jnp.asarray(frame).astype(jnp.uint32)
    seed = jnp.asarray(seed).astype(jnp.uint32)
    key = _hash_u32(seed * jnp.uint32(0x9E3779B9) + frame * jnp.uint32(0x85EBCA6B) + jnp.uint32(0x27D4EB2F))
    if per_pixel:
        r = jnp.asarray(rows).astype(jnp.int32).astype(jnp.uint32)
        c = jnp.asarray(cols).astype(jnp.int32).astype(jnp.uint32)
        key = _hash_u32(_hash_u32(r * jnp.uint32(0x68E31DA4) ^ key) + c * jnp.uint32(0xB5297A4D))
    else:
        key = jnp.where(frame > 0, key, jnp.uint32(0))
        key = jnp.broadcast_to(key, jnp.shape(rows))
    return key >> 8


def spiral_rotation(rows: Array, cols: Array, frame: ArrayLike, seed: ArrayLike, *, per_pixel: bool = True,
                    dtype=jnp.float32) -> Array:
    """Angle (radians, in [0, 2 pi)) by which pixel (``rows``, ``cols``: integer-valued arrays, frame coordinates)
    turns the golden-angle spiral in ``frame`` of a sequence, for ``seed``: a hash of the four, so neighbouring pixels
    and successive frames get unrelated angles (HDRP and EEVEE Next rotate the sample pattern per pixel and per frame
    and leave the noise to TAA). ``per_pixel=False`` turns every pixel by the same angle (the frame's), and frame 0 by
    none: the fixed pattern. The angle depends on no material parameter, so gradients in the material are those of
    the radii."""
    turn = _rotation_turn(rows, cols, frame, seed, per_pixel=per_pixel)
    return turn.astype(dtype) * (2 * math.pi / (1 << 24))  # 24 bits: exact in float32


# ``turn_cos_sin``'s table: cos and sin of 2 pi k / 4096, k < 4096, rounded once from float64 (NumPy's libm)
_TURN_TABLE_BITS = 12
_TURN_TABLE = np.exp(2j * np.pi * np.arange(1 << _TURN_TABLE_BITS) / (1 << _TURN_TABLE_BITS))


def turn_cos_sin(turn: Array, dtype) -> tuple[Array, Array]:
    """cos and sin of ``turn`` (uint32 < 2^24: units of 2^-24 of a turn, ``_rotation_turn``) without a per-element
    trigonometric call: the top 12 bits index a table of 4096 angles, the low 12 bits (an angle b < 2 pi / 4096) enter
    through the angle-sum formulas with Taylor polynomials (cos b to b^4, sin b to b^5: truncation below b^6/720 <
    2e-20, under float64's rounding). XLA's CPU backend calls libm per element for sin and cos (~6-11 ns each): the
    rotation's sin and cos took ~1 ms of a 640x360 call, the table ~0.1 ms."""
    top = (turn >> (24 - _TURN_TABLE_BITS)).astype(jnp.int32)
    b = (turn & jnp.uint32((1 << (24 - _TURN_TABLE_BITS)) - 1)).astype(dtype) * (2 * math.pi / (1 << 24))
    b2 = b * b
    cos_b = 1 - b2 * (0.5 - b2 * (1 / 24))
    sin_b = b * (1 - b2 * (1 / 6 - b2 * (1 / 120)))
    cos_a = jnp.take(jnp.asarray(_TURN_TABLE.real, dtype), top, mode="clip")
    sin_a = jnp.take(jnp.asarray(_TURN_TABLE.imag, dtype), top, mode="clip")
    return cos_a * cos_b - sin_a * sin_b, sin_a * cos_b + cos_a * sin_b


def unit_inverse_ccdf(v: Array) -> Array:
    """``burley_inverse_ccdf(v, 1)`` from exp, log and sqrt only (what every kernel backend lowers, Triton too):
    ``asinh(x) = log(x + sqrt(x^2 + 1))`` and ``2 sinh(a) = exp(a) - exp(-a)``; ``v`` lies in [1/(2S), 1] here,
    where the subtraction loses at most a few bits."""
    v = jnp.clip(v, jnp.finfo(v.dtype).tiny * 2.0**24, 1.0)
    a = jnp.log(2 * v + jnp.sqrt(4 * v * v + 1)) / 3
    return -3 * jnp.log(jnp.minimum(jnp.exp(a) - jnp.exp(-a), 1.0))


def unit_radius_for_cdf(u: Array, inverse_ccdf=unit_inverse_ccdf) -> Array:
    """``_profiles.unit_radius_for_cdf`` (the one definition: ``burley_inverse_cdf`` is it times d) with the closed
    form every kernel backend lowers (``unit_inverse_ccdf``)."""
    return profile_unit_radius_for_cdf(u, inverse_ccdf)


def sample_radius(u: Array, pix: dict, *, truncate: bool, inverse_ccdf=unit_inverse_ccdf) -> Array:
    """The radius, in units of d_max, of the sample at stratified CDF position ``u``: the inverse CDF of the pixel's
    widest-channel profile truncated at the frame's diagonal (per pixel) where ``truncate``, else of the whole
    profile (the tail beyond the diagonal is negligible, ``needs_truncation``: one scalar radius per sample)."""
    if truncate:
        return unit_radius_for_cdf(u * pix["inside"], inverse_ccdf)
    return inverse_ccdf(1 - u)


def needs_truncation(widest_d_px: float, frame_shape: tuple[int, int]) -> bool:
    """Host side: whether the widest profile among the active pixels (``widest_d_px``: its d in px) has more than
    ``TRUNCATION_ENERGY`` of its energy beyond the frame's diagonal (Burley's CCDF ``(exp(-x) + 3 exp(-x/3)) / 4``)."""
    if not widest_d_px > 0:
        return False
    x = math.hypot(*frame_shape) / widest_d_px
    return (math.exp(-x) + 3 * math.exp(-x / 3)) / 4 > TRUNCATION_ENERGY


def active_footprint(d_table: Array, camera, *, depth: Array, valid: Array, rows: Array, min_footprint_px,
                     dtype) -> tuple[Array, Array, Array]:
    """Each pixel's widest d (mm, 0 where it takes no part), its px per mm and whether it is active (it takes
    samples), for pixels of any layout (``depth``: 0 where ``valid`` is false; ``rows``: material rows): what
    ``pixel_planes_at`` computes on and the host's count (``_burley._burley_active``) counts, in the same dtype, so
    that a compacted buffer holds every pixel the pass computes. The widest d is the table row's (exactly the max of
    the pixel's three d), so no (H, W, 3) plane of d is built to count."""
    d_max = jnp.where(valid, jnp.max(d_table, axis=-1)[rows], 0.0)
    ppm = px_per_mm(depth, focal_px=camera.focal_px.astype(dtype), mm_per_unit=camera.mm_per_unit.astype(dtype))
    ppm = jnp.where(valid, ppm, 0.0)
    # pixels whose footprint is below min_footprint_px keep their local shading (no samples are taken for them)
    active = valid & (d_max * ppm * BURLEY_R99 >= min_footprint_px)
    return d_max, ppm, active


def pixel_planes_at(material, camera, *, e: list[Array], z: Array, valid: Array, rows: Array, frow: Array,
                    fcol: Array, min_footprint_px: float, weight_channels: int, dtype,
                    frame_shape: tuple[int, int]) -> tuple[dict, Array]:
    """The per-pixel planes ``sample_term`` reads, for pixels of any layout (each input ``(N,)``: the whole buffer
    flattened, or a compacted set of its pixels), and their active mask ``(N,)``.

    Inputs: ``e`` (3 planes of the prepared irradiance), ``z`` (depth, 0 where ``valid`` is false), ``rows``
    (material rows), ``frow``/``fcol`` (frame coordinates, integers). Planes: ``row``/``col`` (the same as floats),
    ``frow``/``fcol`` (the rotation hash), ``e``, ``z``, ``dmax`` (widest d, mm), ``ppm`` (px per mm), ``inside``
    (the d_max profile's energy within the frame's diagonal) and, per weight channel, ``decay`` (1 / (3 d), 0 where
    d = 0) and ``ok_d`` (d > 0). Each pixel's planes depend on that pixel's inputs alone, so a compacted set
    computes exactly the values the whole frame would hold there."""
    d_table = checked(material.d_mm.astype(dtype), "d_mm")
    d_max, ppm, active = active_footprint(d_table, camera, depth=z, valid=valid, rows=rows,
                                          min_footprint_px=min_footprint_px, dtype=dtype)
    d_w = jnp.where(valid[..., None], d_table[rows][..., :weight_channels], 0.0)  # (N, weight channels)
    inside = jnp.where(d_max > 0, burley_cdf(clip_radius(ppm, frame_shape), d_max), 1.0)
    ok_d = d_w > 0
    decay = jnp.where(ok_d, 1.0 / (3 * jnp.where(ok_d, d_w, 1.0)), 0.0)  # 1 / (3 d), ``burley_weight``'s
    channel = lambda a, c: a[..., c]
    pix = {"row": frow.astype(dtype), "col": fcol.astype(dtype), "frow": frow, "fcol": fcol, "e": list(e), "z": z,
           "dmax": d_max, "ppm": ppm, "inside": inside,
           "decay": [channel(decay, c) for c in range(weight_channels)],
           "ok_d": [channel(ok_d, c) for c in range(weight_channels)]}
    return pix, active


def pixel_planes(buffers, material, camera, prep, *, min_footprint_px: float, weight_channels: int, dtype,
                 origin: tuple[int, int], frame_shape: tuple[int, int]) -> tuple[dict, Array]:
    """``pixel_planes_at`` over the whole buffer (N = H W, flattened), and the active mask (H, W)."""
    h, w = buffers.depth.shape
    flat = lambda a: a.reshape(h * w)
    rows = jnp.broadcast_to(jnp.arange(h, dtype=jnp.int32)[:, None], (h, w)) + origin[0]
    cols = jnp.broadcast_to(jnp.arange(w, dtype=jnp.int32)[None, :], (h, w)) + origin[1]
    pix, active = pixel_planes_at(material, camera, e=[flat(prep.irradiance[..., c]) for c in range(3)],
                                  z=flat(prep.depth), valid=flat(prep.valid), rows=flat(prep.rows), frow=flat(rows),
                                  fcol=flat(cols), min_footprint_px=min_footprint_px,
                                  weight_channels=weight_channels, dtype=dtype, frame_shape=frame_shape)
    return pix, active.reshape(h, w)


# The planes ``fetch`` reads are the buffer's padded by this many pixels of no surface (depth 0) on every side: a
# bilinear footprint's top-left corner is clipped into [-FETCH_PAD, h] (then both rows of the footprint lie outside
# the buffer, or the clip did not move it), so a corner outside the buffer reads "no surface" without a bounds test.
FETCH_PAD = 2


def fetch_planes(pix: dict, buffer_shape: tuple[int, int]) -> list[Array]:
    """R, G, B and depth of the whole buffer (``pix`` of every pixel, before any compaction), padded by
    ``FETCH_PAD`` pixels of no surface and flattened: what ``fetch`` reads at the indices ``sample_place`` gives.
    Separate planes, not one (N, 4) array: on XLA's CPU backend four scalar gathers cost about a quarter of one
    gather of 4-wide rows in the pass, and a gather of each footprint's 2 x 2 x 4 window of a packed (H, W, 4) array,
    4x faster than the 16 scalar gathers alone, is fused into the kernels that read it, which then do not vectorise
    (the pass ran 1.6x slower, 2026-12-02)."""
    return [plane.reshape(-1) for plane in padded_planes(pix, buffer_shape)]


def xla_fetch(planes: list[Array], interpolation: str):
    """``fetch`` for the XLA layouts, over the flattened ``fetch_planes``: ``fetch(idx_q)`` gives R, G, B and depth
    at ``sample_fetch``'s indices. For a bilinear footprint each plane is read as pairs of horizontal neighbours, one
    complex element per footprint row (real part: the pixel, imaginary part: its right neighbour, which the padding
    keeps inside the plane): 8 gathers per sample instead of 16, the same values bit for bit. XLA's CPU gathers cost
    per element, not per byte: the default pass took 0.87 of its time at 640x360, 0.75 at 256x144 (2026-12-02, side
    by side). The pairs are built once per call, outside the sample loop."""
    if interpolation != "bilinear":
        return lambda idx: [jnp.take(plane, idx, mode="clip") for plane in planes]
    pairs = [jax.lax.complex(plane, jnp.concatenate([plane[1:], plane[-1:]])) for plane in planes]

    def fetch(idx_q: Array) -> list[Array]:
        top, bottom = idx_q[0], idx_q[2]  # corners 1 and 3 are their right neighbours (``sample_fetch``)
        rows = [(jnp.take(pair, top, mode="clip"), jnp.take(pair, bottom, mode="clip")) for pair in pairs]
        return [jnp.stack([jnp.real(t), jnp.imag(t), jnp.real(b), jnp.imag(b)]) for t, b in rows]

    return fetch


def padded_planes(pix: dict, buffer_shape: tuple[int, int]) -> list[Array]:
    """``fetch_planes`` before the flattening: four ``(H + 2 FETCH_PAD, W + 2 FETCH_PAD)`` planes. A computation
    that returns them so, for another to flatten (a bitcast), pads ~3-10x faster on XLA's CPU backend: fused with the
    flattening, the pad runs as a loop over the flat index (a division per element, not vectorised), and once per
    consumer (the loop's fetches, the compaction's reads)."""
    h, w = buffer_shape
    return [jnp.pad(plane.reshape(h, w), FETCH_PAD) for plane in (*pix["e"], pix["z"])]


def sample_place(i: Array | int, samples: int, cos_phi: Array, sin_phi: Array, pix: dict, *,
                 buffer_shape: tuple[int, int], origin: Origin, frame_shape: tuple[int, int],
                 interpolation: str, truncate: bool, border: str, inverse_ccdf=unit_inverse_ccdf) -> dict:
    """Where sample ``i`` of ``samples`` lands for each pixel: the first half of ``sample_term``.

    The sample's radius is the stratified inverse CDF of the pixel's widest-channel profile (truncated at the frame's
    diagonal where ``truncate``), its angle the golden-angle spiral's turned by the pixel's rotation (``cos_phi``,
    ``sin_phi``); it is placed in mm on the surface and projected with the pixel's px/mm. Returns ``rho`` (the radius
    in units of d_max: one scalar per sample unless ``truncate``), ``inv_pdf`` (1 / pdf of that radius up to the
    per-pixel factor 8 pi d_max^2), ``idx`` (the fetch index, in ``fetch_planes``' padded layout, of the nearest pixel
    or of the bilinear footprint's top-left corner), ``fx``/``fy`` (bilinear: the position within the footprint) and,
    with ``border="leaves"``, ``in_frame`` (the part of the fetch inside the frame)."""
    dtype = pix["z"].dtype
    u, theta = spiral_sample(jnp.asarray(i).astype(dtype), samples)
    rho = sample_radius(u, pix, truncate=truncate, inverse_ccdf=inverse_ccdf)  # in units of d_max
    off = rho * pix["dmax"] * pix["ppm"]
    cos_t = jnp.cos(theta) * cos_phi - jnp.sin(theta) * sin_phi  # the spiral turned by the pixel's angle
    sin_t = jnp.sin(theta) * cos_phi + jnp.cos(theta) * sin_phi
    place = {"rho": rho, "inv_pdf": rho / (jnp.exp(-rho) + jnp.exp(-rho / 3))}
    height, width = frame_shape
    h, w = buffer_shape
    # frame coordinates; clip first: huge or NaN offsets must not overflow the integer cast
    y = jnp.clip(jnp.where(jnp.isnan(off), -4.0, pix["row"] + off * sin_t), -4.0, height + 3.0)
    x = jnp.clip(jnp.where(jnp.isnan(off), -4.0, pix["col"] + off * cos_t), -4.0, width + 3.0)
    row0, col0 = origin
    padded_width = w + 2 * FETCH_PAD
    index = lambda ly, lx: (ly + FETCH_PAD).astype(jnp.int32) * padded_width + (lx + FETCH_PAD).astype(jnp.int32)
    rows_in = lambda yi: (yi >= 0) & (yi <= height - 1)
    cols_in = lambda xi: (xi >= 0) & (xi <= width - 1)
    if interpolation == "nearest":
        yi, xi = jnp.round(y), jnp.round(x)
        place["idx"] = index(jnp.clip(yi - row0, -1, h), jnp.clip(xi - col0, -1, w))
        in_frame = jnp.where(rows_in(yi) & cols_in(xi), 1.0, 0.0)
    else:
        y0, x0 = jnp.floor(y), jnp.floor(x)
        place["fy"], place["fx"] = fy, fx = y - y0, x - x0
        place["idx"] = index(jnp.clip(y0 - row0, -FETCH_PAD, h), jnp.clip(x0 - col0, -FETCH_PAD, w))
        # the four corners' weights are products of a row's and a column's: so is their sum over the frame
        in_frame = ((jnp.where(rows_in(y0), 1 - fy, 0.0) + jnp.where(rows_in(y0 + 1), fy, 0.0))
                    * (jnp.where(cols_in(x0), 1 - fx, 0.0) + jnp.where(cols_in(x0 + 1), fx, 0.0)))
    if border == "leaves":
        place["in_frame"] = in_frame
    return place


def sample_fetch(place: dict, fetch, *, buffer_shape: tuple[int, int], interpolation: str) -> dict:
    """``place`` (``sample_place``) with what its fetch reads: ``e_q`` (R, G, B) and ``z_q`` (depth), each
    ``(corners, N)``, at the nearest pixel or the bilinear footprint's four corners (``fetch(idx)`` reads the planes of
    ``fetch_planes`` at the indices ``idx``).

    Apart from ``sample_place`` so that a loop can place a sample an iteration ahead and fetch it in the next
    (``_burley_gpu.frame_result``)."""
    idx = place["idx"]
    if interpolation == "nearest":
        idx_q = idx[None]
    else:
        step = buffer_shape[1] + 2 * FETCH_PAD  # one row down in the padded planes
        idx_q = jnp.stack([idx, idx + 1, idx + step, idx + step + 1])
    *e_q, z_q = fetch(idx_q)
    return {**place, "e_q": e_q, "z_q": z_q}


def sample_weights(place: dict, pix: dict, *, mm_per_unit: Array, interpolation: str, weight_channels: int,
                   border: str) -> tuple[Array, Array]:
    """What a sample at ``place`` (``sample_place``, its pixels read by ``sample_fetch``) adds to each pixel's
    numerator (``(3, N)``: R, G, B) and denominator (``(weight_channels, N)``): the second half of ``sample_term``.

    Each pixel q a bilinear (or nearest) fetch reads is its own point on the surface: it adds
    ``frac_q R_c(sqrt(r^2 + dz^2)) / pdf(r)`` to the channel's denominator and that times ``e_q`` to its numerator
    (no interpolated depth across a step). Pixels without a surface, and pixels of the frame outside this buffer (the
    padding of ``fetch_planes``: depth 0), add nothing; with ``border="leaves"`` the part of the fetch outside the
    frame adds the weight of dark surface at the pixel's own depth (``R_c(r) / pdf(r)``) to the denominator only:
    that light leaves the frame.

    The corners and the channels are leading axes of arrays (corners x channels x pixels), not lists of planes: XLA
    then computes all of a sample's fetches, kernels and sums in a handful of fusions instead of one per corner and
    channel (each a pass over the pixels)."""
    inv_pdf = place["inv_pdf"]
    r_mm = place["rho"] * pix["dmax"]
    e_q, z_q = place["e_q"], place["z_q"]  # each (corners, N)
    if interpolation == "nearest":
        frac = jnp.ones(z_q.shape, r_mm.dtype)
    else:
        fx, fy = place["fx"], place["fy"]
        frac = jnp.stack([(1 - fy) * (1 - fx), (1 - fy) * fx, fy * (1 - fx), fy * fx])
    ok = z_q > 0  # validity travels in the depth (0 where a pixel takes no part, and in the padding)
    v_q = jnp.where(ok, frac, 0.0)
    dz_mm = jnp.where(ok, (z_q - pix["z"][None]) * mm_per_unit, 0.0)
    # the distance floored at 1e-15 mm (a square of 1e-30, a normal float32) rather than ``_safe_sqrt``'s double
    # where: the same value wherever the kernel is not 0 anyway (r = 0 only with d_max = 0), a finite gradient at
    # r = 0, and XLA then reads the root's result in the kernel instead of recomputing its argument there
    r3 = jnp.sqrt(jnp.maximum((r_mm * r_mm)[None] + dz_mm * dz_mm, 1e-30))
    base = v_q * (inv_pdf[None] if jnp.ndim(inv_pdf) else inv_pdf)
    channels = lambda key: jnp.stack(pix[key])  # (weight_channels, N)
    decay, ok_d = channels("decay"), channels("ok_d")
    r0, tail = pix.get("r0"), (channels("tail") if "tail" in pix else None)  # ``weight_offset``, where given
    wgt = burley_weight(r3[:, None], decay[None], ok_d[None], base[:, None],  # (corners, channels, N)
                        None if r0 is None else r0[None, None], None if tail is None else tail[None])
    corners = range(wgt.shape[0])
    # a grey weight (channel 0) serves the three channels; each channel's gathers stay inside its sum
    num = jnp.stack([sum(wgt[q, min(c, weight_channels - 1)] * e_q[c][q] for q in corners) for c in range(3)])
    den = sum(wgt[q] for q in corners)
    if border == "leaves":
        out = 1 - place["in_frame"]
        if weight_channels == 1:  # grey: the weight at dz = 0 is R/pdf of the sampled profile itself, 1 / d_max
            den = den + (out * (3 * pix["decay"][0]))[None]
        else:
            den = den + burley_weight(r_mm[None], decay, ok_d, (out * inv_pdf)[None],
                                      None if r0 is None else r0[None], tail)
    return num, den


def sample_term(i: Array | int, samples: int, cos_phi: Array, sin_phi: Array, pix: dict, fetch, *,
                buffer_shape: tuple[int, int], origin: Origin, frame_shape: tuple[int, int],
                mm_per_unit: Array, interpolation: str, weight_channels: int, truncate: bool, border: str,
                inverse_ccdf=unit_inverse_ccdf) -> tuple[Array, Array]:
    """What sample ``i`` of ``samples`` adds to each pixel's numerator (``(3, N)``) and denominator
    (``(weight_channels, N)``): the one definition of the pass (Christensen & Burley 2015, screen space), in two halves:
    where the sample lands (``sample_place``, its pixels read by ``sample_fetch``) and what it weighs there
    (``sample_weights``).

    ``pix``: the planes of ``pixel_planes`` for this layout's pixels; ``fetch(idx)``: R, G, B and depth at index
    ``idx`` of ``fetch_planes`` (the buffer padded by pixels of no surface). Layout-free (a frame, a compacted set or
    a Pallas block of pixels)."""
    place = sample_place(i, samples, cos_phi, sin_phi, pix, buffer_shape=buffer_shape, origin=origin,
                         frame_shape=frame_shape, interpolation=interpolation, truncate=truncate, border=border,
                         inverse_ccdf=inverse_ccdf)
    place = sample_fetch(place, fetch, buffer_shape=buffer_shape, interpolation=interpolation)
    return sample_weights(place, pix, mm_per_unit=mm_per_unit, interpolation=interpolation,
                          weight_channels=weight_channels, border=border)


def normalise(num: list[Array], den: list[Array], e: list[Array]) -> list[Array]:
    """Each channel's weighted mean (``weighted_mean``); a pixel no sample reached keeps its own value."""
    out = []
    for c in range(3):
        d = den[min(c, len(den) - 1)]
        ok = d > 0
        out.append(jnp.where(ok, weighted_mean(num[c], jnp.where(ok, d, 1.0)), e[c]))
    return out


def frame_rotation(pix: dict, frame: ArrayLike, seed: ArrayLike, *, pattern: str) -> tuple[Array, Array]:
    """cos and sin of each pixel's rotation of the spiral in ``frame`` (``spiral_rotation`` at frame coordinates,
    through ``turn_cos_sin``)."""
    turn = _rotation_turn(pix["frow"], pix["fcol"], frame, seed, per_pixel=pattern == "rotated")
    return turn_cos_sin(turn, pix["z"].dtype)


def burley_reach_px(widest_d_px: float, frame_shape: tuple[int, int], samples: int,
                    interpolation: str = "bilinear") -> int:
    """Host side: how far (px, along a row or a column) a pixel's fetches reach: the outermost sample of the widest
    active profile (the largest stratified CDF value ``(n - 1/2) / n``; truncation at the frame's diagonal only draws
    it closer) lands at most ``ceil(rho d)`` pixels away, rounded to the nearest pixel or, bilinear, with the
    footprint's second pixel one further; no further than the frame's larger extent (a fetch beyond it is outside the
    frame). The halo a tile needs so that its pixels are the untiled frame's."""
    if not widest_d_px > 0:
        return 0
    rho = unit_radius(0.5 / samples)
    reach = math.ceil(min(rho * widest_d_px, math.hypot(*frame_shape))) + (1 if interpolation == "bilinear" else 0)
    return int(min(reach, max(frame_shape)))
