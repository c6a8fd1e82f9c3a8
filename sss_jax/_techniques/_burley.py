"""Screen-space Christensen–Burley normalised diffusion: one pass of golden-angle spiral samples per pixel."""

from __future__ import annotations

import functools
import math
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import checked
from .._kernels import spiral_samples
from .._materials import BurleyMaterial
from .._profiles import burley_cdf, burley_inverse_ccdf
from .._scene import Buffers, Camera
from .._units import px_per_mm
from ._common import (
    MIN_FOOTPRINT_PX,
    SamplingWarning,
    _check_albedo_mode,
    _check_border,
    _corners,
    _finish,
    _is_concrete,
    _material_rows,
    _pack,
    _prepare,
    _safe_sqrt,
    _sss_mask,
    _work_dtype,
)
from ._dispatch import resolve_impl


def _burley_weight_kernel(x: Array) -> Array:
    """``(exp(-x) + exp(-x/3)) / x``: the Burley profile at ``r = x d`` up to the factor ``8 pi d^2`` that cancels in
    the per-channel normalisation. ``x = inf`` (d = 0 or no overlap) gives 0; x is never 0 here (r > 0)."""
    finite = jnp.isfinite(x) & (x > 0)
    xs = jnp.where(finite, x, 1.0)
    e3 = jnp.exp(-xs / 3)  # exp(-x) = e3^3: one exponential, not two
    return jnp.where(finite, e3 * (e3 * e3 + 1) / xs, 0.0)




BURLEY_PATTERNS = ("rotated", "fixed")


def _hash_u32(x: Array) -> Array:
    """A 32-bit integer hash (Wellons' ``lowbias32``): consecutive inputs give unrelated outputs."""
    x = x.astype(jnp.uint32)
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x7FEB352D)
    x = x ^ (x >> 15)
    x = x * jnp.uint32(0x846CA68B)
    return x ^ (x >> 16)


def spiral_rotation(rows: Array, cols: Array, frame: Array | int, seed: Array | int, *, per_pixel: bool = True,
                    dtype=jnp.float32) -> Array:
    """Angle (radians, in [0, 2 pi)) by which pixel (``rows``, ``cols``: integer-valued arrays) turns the golden-angle
    spiral in ``frame`` of a sequence, for ``seed``: a hash of the four, so neighbouring pixels and successive frames
    get unrelated angles (HDRP and EEVEE Next rotate the sample pattern per pixel and per frame and leave the noise to
    TAA). ``per_pixel=False`` turns every pixel by the same angle (the frame's), and frame 0 by none: the fixed
    pattern. The angle depends on no material parameter, so gradients in the material are those of the radii."""
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
    unit = (key >> 8).astype(dtype) * (1.0 / (1 << 24))  # 24 bits: exact in float32
    return unit * (2 * math.pi)


def _unit_radius_for_cdf(u: Array) -> Array:
    """Radius (units of d) holding the fraction ``u`` in (0, 1) of a Burley profile's energy, with full relative
    precision for tiny ``u`` (a kernel far wider than the image keeps only ~r/(2d) of its energy there; ``1 - u``
    would round to 1). With ``s = 1 - exp(-r/(3d))`` the CDF is ``(6s - 3s^2 + s^3)/4``: Newton from ``2u/3`` where u
    is small, the closed form (``burley_inverse_ccdf``) elsewhere."""
    small = u < 0.5
    us = jnp.where(small, u, 0.25)
    s = 2 * us / 3
    for _ in range(4):  # f' = 3 s^2 - 6 s + 6 >= 3: Newton converges fast from 2u/3 for u < 0.5
        s = s - (s * (6 - 3 * s + s * s) - 4 * us) / (3 * s * s - 6 * s + 6)
    near = -3 * jnp.log1p(-s)
    far = burley_inverse_ccdf(1 - jnp.where(small, 0.75, u), jnp.ones_like(u))
    return jnp.where(small, near, far)


# radius holding 99% of a Burley profile's energy, in units of d (the footprint the skip and compaction test)
_BURLEY_R99 = float(np.asarray(burley_inverse_ccdf(np.float64(0.01), np.float64(1.0))))


@eqx.filter_jit
def _burley_impl(buffers: Buffers, material: BurleyMaterial, camera: Camera, samples: int, albedo_mode: str,
                 interpolation: str, capacity: int | None, min_footprint_px: float, weight_channels: int = 3,
                 truncate: bool = True, pattern: str = "rotated", frames: int = 1, seed: Array | int = 0,
                 border: str = "leaves") -> Array:
    dtype = _work_dtype(buffers.irradiance.dtype)
    d_table = checked(material.d_mm.astype(dtype), "d_mm")
    prep = _prepare(buffers, material.albedo, albedo_mode, dtype)
    h, w = buffers.depth.shape
    mm_per_unit = camera.mm_per_unit.astype(dtype)
    d_pix = jnp.where(prep.valid[..., None], d_table[prep.rows], 0.0)  # (H, W, 3)
    d_max = jnp.max(d_pix, axis=-1)
    ppm = px_per_mm(prep.depth, focal_px=camera.focal_px.astype(dtype), mm_per_unit=mm_per_unit)
    ppm = jnp.where(prep.valid, ppm, 0.0)
    # pixels whose footprint is below min_footprint_px keep their local shading (no samples are taken for them)
    active = prep.valid & (d_max * ppm * _BURLEY_R99 >= min_footprint_px)
    flat = _pack(prep.irradiance, prep.depth, prep.valid)
    # Cost follows the scene: with a capacity, only the active pixels (compacted into a buffer of that many slots,
    # unused slots pointing past the image) are computed and scattered back; without one every pixel is.
    if capacity is None:
        idx = jnp.arange(h * w, dtype=jnp.int32)
        take = lambda a: a.reshape(h * w, *a.shape[2:])
    else:
        idx = jnp.nonzero(active.reshape(-1), size=capacity, fill_value=h * w)[0].astype(jnp.int32)
        take = lambda a: jnp.take(a.reshape(h * w, *a.shape[2:]), idx, axis=0, mode="fill", fill_value=0)
    e_c, z, d_c, ppm_c, dmax_c = take(prep.irradiance), take(prep.depth), take(d_pix), take(ppm), take(d_max)
    rows_int, cols_int = idx // w, idx % w
    rows_i = rows_int.astype(dtype)
    cols_i = cols_int.astype(dtype)
    # Samples beyond the image diagonal can never land: sample the profile truncated there (huge d clamps to the
    # image instead of losing every sample); the energy beyond it leaves the frame (out_of_frame_mass below).
    diag_px = math.hypot(h, w)
    r_clip = jnp.where(ppm_c > 0, diag_px / jnp.where(ppm_c > 0, ppm_c, 1.0), jnp.inf)
    inside_fraction = jnp.where(dmax_c > 0, burley_cdf(jnp.minimum(r_clip, 1e30), dmax_c), 1.0)
    # channels with one d (grey materials) share one weight: the kernel is evaluated once, not per channel
    d_w = d_c[..., :weight_channels]
    ok_d = d_w > 0
    inv_d = jnp.where(ok_d, 1.0 / jnp.where(ok_d, d_w, 1.0), 0.0)
    ok_dmax = dmax_c > 0
    inv_dmax = jnp.where(ok_dmax, 1.0 / jnp.where(ok_dmax, dmax_c, 1.0), 0.0)
    leaves = border == "leaves"
    beyond = out_of_frame_mass(d_w, dmax_c, inv_dmax, r_clip, inside_fraction, samples) if truncate and leaves else None

    # channel planes: every per-pixel quantity below is a 1D array over the pixels, which XLA vectorises along
    # (an (N, 3) layout leaves 3 lanes in the minor dimension)
    inv_d_planes = [inv_d[:, c] for c in range(weight_channels)]
    ok_d_planes = [ok_d[:, c] for c in range(weight_channels)]

    spiral = spiral_samples(samples, dtype=dtype)  # the one owner of the sample pattern

    def one_frame(cos_phi, sin_phi):
        def body(i, acc):
            num, den = acc
            if truncate:
                u = spiral.cdf[i] * inside_fraction  # stratified CDF, truncated to the image
                rho = _unit_radius_for_cdf(u)  # radius in units of d_max
            else:  # no profile reaches past the image diagonal by more than rounding (decided on the host): every
                # pixel shares the sample radius, one scalar inverse CDF per sample, not one per pixel and sample
                rho = burley_inverse_ccdf(1 - spiral.cdf[i], jnp.ones((), dtype))
            r_mm = rho * dmax_c
            off = r_mm * ppm_c
            theta = spiral.angles[i]
            # the spiral turned by the pixel's angle: cos/sin of the sum, one scalar pair per sample
            cos_t = jnp.cos(theta) * cos_phi - jnp.sin(theta) * sin_phi
            sin_t = jnp.sin(theta) * cos_phi + jnp.cos(theta) * sin_phi
            # 1 / pdf of this sample (area density of the d_max profile at r), up to the per-pixel factor 8 pi d_max^2
            inv_pdf = rho / (jnp.exp(-rho) + jnp.exp(-rho / 3))
            # each pixel the fetch reads is its own point on the surface, with its own depth: weighting the corners
            # separately keeps light from leaking across a depth step through the interpolation
            num, den = list(num), list(den)
            in_frame = 0.0
            for val, bw in _corners(flat, h, w, rows_i + off * sin_t, cols_i + off * cos_t,
                                    interpolation=interpolation):
                in_frame = in_frame + bw
                v_q = val[..., 4] * bw
                dz_mm = jnp.where(v_q > 0, (val[..., 3] - z) * mm_per_unit, 0.0)
                r3 = _safe_sqrt(r_mm * r_mm + dz_mm * dz_mm)
                base = v_q * inv_pdf
                wgt = [base * _burley_weight_kernel(jnp.where(ok_d_planes[c], r3 * inv_d_planes[c], jnp.inf))
                       for c in range(weight_channels)]
                for c in range(3):
                    num[c] = num[c] + wgt[min(c, weight_channels - 1)] * val[..., c]
                for c in range(weight_channels):
                    den[c] = den[c] + wgt[c]
            # the part of the fetch that fell outside the frame: dark surface at the pixel's own depth (light that
            # scatters out of the frame leaves; it is not pushed back onto the pixels inside)
            if leaves and weight_channels == 1:  # grey: the weight at dz = 0 is R/pdf of the sampled profile itself, 1
                den[0] = den[0] + (1 - in_frame) * ok_d_planes[0]
            elif leaves:
                out_w = (1 - in_frame) * inv_pdf
                for c in range(weight_channels):
                    den[c] = den[c] + out_w * _burley_weight_kernel(
                        jnp.where(ok_d_planes[c], r_mm * inv_d_planes[c], jnp.inf))
            return tuple(num), tuple(den)

        zeros = jnp.zeros(e_c.shape[:1], dtype)
        num, den = jax.lax.fori_loop(0, samples, body, ((zeros,) * 3, (zeros,) * weight_channels))
        num, den = jnp.stack(num, axis=-1), jnp.stack(den, axis=-1)
        if beyond is not None:
            den = den + beyond
        ok = jnp.broadcast_to(den > 0, num.shape)
        return jnp.where(ok, num / jnp.where(ok, den, 1.0), e_c)

    def frame_result(k):
        phi = spiral_rotation(rows_int, cols_int, k, seed, per_pixel=pattern == "rotated", dtype=dtype)
        return one_frame(jnp.cos(phi), jnp.sin(phi))

    if frames == 1:
        result = frame_result(0)
    else:  # temporal accumulation: the mean of ``frames`` frames, each with its own rotations (converged TAA)
        result = jax.lax.fori_loop(0, frames, lambda k, acc: acc + frame_result(k), jnp.zeros_like(e_c)) / frames
    if capacity is None:
        scattered = result.reshape(h, w, 3)
    else:
        scattered = prep.irradiance.reshape(h * w, 3).at[idx].set(result, mode="drop").reshape(h, w, 3)
    scattered = jnp.where(active[..., None], scattered, prep.irradiance)
    return _finish(buffers, prep, scattered)


def out_of_frame_mass(d_w: Array, d_max: Array, inv_d_max: Array, r_clip: Array, inside_fraction: Array,
                      samples: int) -> Array:
    """The energy of each channel's profile beyond ``r_clip`` (the image diagonal, mm: it lands outside the frame
    from every pixel), in the units of the sample weights' sum: the weights of ``samples`` samples drawn from the
    d_max profile truncated at ``r_clip`` (which holds ``inside_fraction`` of its energy) are ``R_c / pdf`` times
    ``(d_c / d_max)^2`` (the kernel drops the factor ``8 pi d^2``), so a mass m counts as
    ``m samples / inside_fraction (d_c / d_max)^2``."""
    leave = 1 - burley_cdf(jnp.minimum(r_clip, 1e30)[:, None], d_w)
    ok = inside_fraction > 0
    per_weight = samples / jnp.where(ok, inside_fraction, 1.0)
    return jnp.where(ok[:, None], leave * per_weight[:, None] * (d_w * inv_d_max[:, None]) ** 2, 0.0)


def compaction_capacity(active_count: int, pixels: int, *, minimum: int = 256) -> int | None:
    """Slots of the compacted buffer for ``active_count`` active pixels out of ``pixels``: the next power of two (so
    a sequence of frames compiles once per bucket, not once per count), or ``None`` (dense) where that would hold at
    least half the frame anyway."""
    capacity = max(minimum, 1 << max(0, int(active_count) - 1).bit_length())
    return None if capacity * 2 > pixels else capacity


def burley_active_count(buffers: Buffers, material: BurleyMaterial, camera: Camera, *,
                        min_footprint_px: float = MIN_FOOTPRINT_PX) -> int:
    """Host side: how many pixels ``burley`` computes (SSS pixels whose footprint reaches ``min_footprint_px``)."""
    return _burley_active(buffers, material, camera, min_footprint_px)[0]


def _burley_active(buffers: Buffers, material: BurleyMaterial, camera: Camera, min_footprint_px: float):
    """Host side: the number of active pixels and the largest widest-channel d among them, in px (0 if none)."""
    depth = np.asarray(buffers.depth, np.float64)
    valid = np.asarray(_sss_mask(buffers))
    d = np.asarray(material.d_mm, np.float64).reshape(-1, 3).max(axis=-1)
    rows = np.asarray(_material_rows(buffers, d.shape[0]))
    safe = np.where(valid & np.isfinite(depth) & (depth > 0), depth, np.inf)
    ppm = float(camera.focal_px) / (safe * float(camera.mm_per_unit))
    d_px = d[rows] * ppm
    active = valid & (d_px * _BURLEY_R99 >= min_footprint_px)
    return int(np.count_nonzero(active)), float(np.max(d_px, where=active, initial=0.0))


def burley(
    buffers: Buffers,
    material: BurleyMaterial,
    camera: Camera,
    *,
    samples: int = 32,
    albedo_mode: str = "post",
    interpolation: str = "bilinear",
    min_footprint_px: float = MIN_FOOTPRINT_PX,
    compact: bool | None = None,
    impl: str = "auto",
    pattern: str = "rotated",
    frames: int = 1,
    seed: int | Array = 0,
    border: str = "renormalise",
) -> Float[Array, "H W 3"]:
    """Screen-space Christensen–Burley normalised diffusion (one pass, ``samples`` spiral samples per pixel).

    Each sample's radius comes from stratified inverse-CDF sampling of the widest channel's profile (so one fetch
    serves R, G and B), its angle from the golden-angle spiral; it is placed in millimetres on the surface and
    projected with the pixel's depth. Its weight per channel is ``R_c(sqrt(r^2 + dz^2)) / pdf(r)`` (the depth
    difference dz makes light fall off across depth steps), and the weights are normalised per channel so flat
    lighting stays flat: energy is redistributed, not created. ``interpolation="bilinear"`` (default) makes the
    result continuous in d and depth (smooth for fitting); ``"nearest"`` (what HDRP does) fetches one pixel per
    sample, a quarter of the fetches and kernel evaluations, ~3.5x faster on a CPU, at some accuracy (demo scene,
    32 samples, rel. L2 against the reference: 0.0127 against 0.0118; point light 0.47 against 0.29; and more
    sampling noise where the footprint spans few pixels).

    The spiral turns per pixel by a hash of the pixel, the frame and ``seed`` (``pattern="rotated"``, the default,
    as HDRP and EEVEE Next do: the sampling error is noise, not a pattern shared by every pixel that blurs edges
    asymmetrically and draws ghost stripes), or not at all (``pattern="fixed"``: every pixel the same spiral, the
    behaviour before; it conserves energy exactly on a plane, the rotated one in expectation). ``frames=K`` averages
    K frames, each with its own rotations: the converged temporal accumulation (TAA) the engines rely on, at K
    times the cost. ``seed`` (an integer, traced: a new seed does not recompile) picks the rotations, e.g. the frame
    number of a sequence. With concrete inputs, a channel much narrower than the widest one, which the samples
    (drawn from the widest profile) barely reach, raises a ``SamplingWarning`` with the error it implies.

    Cost follows the scene: pixels without SSS, and pixels whose footprint (the radius holding 99% of the widest
    channel's energy, in px) is below ``min_footprint_px`` (they keep their local shading, the paper's Fig. 1; 0
    disables that), take no samples. With concrete (not traced) inputs the active pixels are counted on the host and
    compacted into a buffer of the next power-of-two size (one compilation per size bucket), computed, and scattered
    back; ``compact=None`` (default) does so where the bucket holds under half the frame, ``True`` always, ``False``
    never. Under ``jit``/``vmap`` every pixel is computed (one compilation per shape). Compacted and dense results
    agree to rounding. Channels that share one d (a grey material, or every material grey) share one kernel
    evaluation per sample instead of three; the result is the same.

    The frame border (``border``): by default (``"renormalise"``) the samples landing outside the image are dropped
    and the kernel renormalised over the ones inside, as if the surface beyond looked like the inside -- what every
    engine does (HDRP skips off-frame samples and divides by the weights it kept), and on path-traced frames the
    better rule (README, "Defaults on real frames": the Cycles frame 0.95 of local shading's error against 1.03 with
    ``"leaves"``). With ``border="leaves"``, for a surface that really ends at the frame, light that scatters out of
    the frame leaves: a sample (or the part of a bilinear fetch) landing outside the image counts, in the
    normalisation, as dark surface at the pixel's own depth, and the profile's energy beyond the image diagonal is
    counted the same way; samples on pixels without a surface inside the frame are dropped from the normalisation
    (the light there is taken as if it came from the pixels with a surface). So a lit spot keeps, over the frame,
    the fraction of its energy whose profile lies inside it, and as d grows past the frame every pixel tends to the
    same small share of the frame's light (more blur, never a return to the input). (The renormalised default is
    right where a lit surface is cut by the frame.)

    ``impl`` (``_dispatch``): "auto" runs the formulation above on a CPU backend ("xla-cpu") and elsewhere the
    whole-frame one with no host round trip ("xla-gpu": every pixel computed and masked, ``compact`` unused, three
    kernel evaluations per sample); "pallas" is that as one Pallas kernel (blocks without active pixels skip it).
    The whole-frame formulations have the fixed spiral and the renormalised border so far (``pattern="fixed"``,
    ``border="renormalise"``, one frame): with other options "auto" keeps the formulation above on any backend,
    and naming "xla-gpu" or "pallas" is an error.
    """
    _check_albedo_mode(albedo_mode)
    if interpolation not in ("bilinear", "nearest"):
        raise ValueError(f"interpolation={interpolation!r} is not one of ('bilinear', 'nearest')")
    if not isinstance(material, BurleyMaterial):
        raise TypeError(f"burley needs a BurleyMaterial, got {type(material).__name__}")
    if not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ValueError(f"samples must be a positive integer, got {samples!r}")
    if not (float(min_footprint_px) >= 0):
        raise ValueError(f"min_footprint_px must be >= 0, got {min_footprint_px!r}")
    _check_border(border)
    if pattern not in BURLEY_PATTERNS:
        raise ValueError(f"pattern={pattern!r} is not one of {BURLEY_PATTERNS}")
    if not isinstance(frames, (int, np.integer)) or isinstance(frames, bool) or frames < 1:
        raise ValueError(f"frames must be a positive integer, got {frames!r}")
    if _is_concrete(seed) and not (np.ndim(seed) == 0 and float(seed) == int(seed) and 0 <= int(seed) < 2**32):
        raise ValueError(f"seed must be an integer in [0, 2**32), got {seed!r}")
    seed = jnp.asarray(np.uint32(int(seed)) if _is_concrete(seed) else seed).astype(jnp.uint32)
    which = resolve_impl(impl)
    gpu_semantics = pattern == "fixed" and border == "renormalise" and frames == 1
    if which != "xla-cpu" and not gpu_semantics:
        if impl != "auto":
            raise ValueError(f"impl={impl!r} has the fixed spiral and the renormalised border only so far: pass "
                             "pattern='fixed', border='renormalise', frames=1, or impl='auto'/'xla-cpu'")
        which = "xla-cpu"  # the formulation above runs on every backend
    if which != "xla-cpu":  # no host count, no host read of d: nothing waits for the device
        from ._burley_gpu import burley_gpu_impl

        return burley_gpu_impl(buffers, material, camera, int(samples), albedo_mode, interpolation,
                               float(min_footprint_px), 3, which)
    capacity, truncate = None, True
    weight_channels = weight_channel_count(material.d_mm)
    if _is_concrete(buffers, material, camera):
        h, w = buffers.depth.shape[-2:]
        count, reach_px = _burley_active(buffers, material, camera, float(min_footprint_px))
        truncate = reach_px * _untruncated_radius(buffers.irradiance.dtype) > math.hypot(h, w)
        if compact is not False:
            capacity = compaction_capacity(count, h * w)
            if compact and capacity is None:
                capacity = 1 << max(0, count - 1).bit_length()
        if count:
            worst = burley_channel_samples(material.d_mm, int(samples) * int(frames))
            if worst is not None and worst[0] < 4:
                n_eff, m, c = worst
                d = np.asarray(material.d_mm, np.float64)
                implied = min(1.0, 0.5 / math.sqrt(max(n_eff, 1e-9)))
                warnings.warn(f"burley: channel {'RGB'[c]} of material {m + 1} (d {d[m, c]:.3g} mm, the widest "
                              f"{d[m].max():.3g} mm) gets {n_eff:.2g} of {samples * frames} samples within the radius "
                              f"holding 95% of its energy: its kernel is not represented (per-pixel error up to "
                              f"{implied:.2f} of an edge's contrast); more samples or frames", SamplingWarning,
                              stacklevel=2)
    return _burley_impl(buffers, material, camera, int(samples), albedo_mode, interpolation, capacity,
                        float(min_footprint_px), weight_channels, bool(truncate), pattern, int(frames), seed,
                        border)


def burley_channel_samples(d_mm, samples: int):
    """Host side: the fewest samples any channel of any material gets within the radius holding 95% of its own
    energy (samples follow the widest channel's profile, so a channel much narrower than it sees only the innermost
    few): ``(expected samples, material row, channel)``, or ``None`` when no channel has d > 0. ``samples`` counts
    every frame's. Below a few, that channel's kernel is not represented: its result rests on one or two fetches."""
    d = np.asarray(d_mm, np.float64).reshape(-1, 3)
    d_max = d.max(axis=1, keepdims=True)
    ok = d > 0
    if not ok.any():
        return None
    r95 = _BURLEY_R95 * d
    x = np.where(ok, r95 / np.where(d_max > 0, d_max, 1.0), 0.0)
    share = 1 - np.exp(-x) / 4 - 3 * np.exp(-x / 3) / 4  # Burley's CDF (Christensen & Burley 2015)
    n_eff = np.where(ok, samples * share, np.inf)
    m, c = np.unravel_index(np.argmin(n_eff), n_eff.shape)
    return float(n_eff[m, c]), int(m), int(c)


_BURLEY_R95 = float(np.asarray(burley_inverse_ccdf(np.float64(0.05), np.float64(1.0))))


@functools.lru_cache(maxsize=None)
def _untruncated_radius(dtype) -> float:
    """Radius (units of d) beyond which the Burley profile's remaining energy rounds away in ``dtype``: a pixel
    whose image diagonal is farther than this needs no truncated sampling."""
    eps = float(jnp.finfo(_work_dtype(dtype)).eps)
    return float(np.asarray(burley_inverse_ccdf(np.float64(eps / 4), np.float64(1.0))))


def weight_channel_count(d_mm) -> int:
    """Host side: 1 where every material's d is the same in R, G and B (one kernel serves the three channels, so
    ``burley`` evaluates it once), else 3. Traced d (under ``jit``/``grad``) always gives 3."""
    if not _is_concrete(d_mm):
        return 3
    d = np.asarray(d_mm).reshape(-1, 3)
    return 1 if np.array_equal(d, np.broadcast_to(d[:, :1], d.shape)) else 3

