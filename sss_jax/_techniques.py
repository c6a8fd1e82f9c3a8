"""The four screen-space techniques, each a jitted function of (buffers, material parameters, camera).

- ``translucency`` (STA): local, adds back-light through thickness. Does NOT conserve energy (it adds light).
- ``separable`` (SSSS): a horizontal then a vertical 1D pass, depth-aware ("follow the surface").
- ``burley``: one pass of n golden-angle spiral samples of the Christensen–Burley profile, normalised.
- ``reference``: dense, brute-force convolution with the exact profile integrated over each pixel's footprint.

``separable``, ``burley`` and ``reference`` redistribute light: each output pixel is a normalised weighted mean of
irradiance, so flat lighting stays flat and energy is conserved away from image and depth borders.

Common behaviour: a pixel takes part when it has a surface (finite positive depth) and, if a ``material_id`` buffer
is given, a non-zero id; every other pixel passes through untouched (output = input irradiance). The output of
an SSS pixel is ``albedo * scattered irradiance`` (``albedo_mode="post"``) or, with ``albedo_mode="pre_post"``,
``sqrt(albedo) * scatter(sqrt(albedo) * irradiance)`` (texture detail survives the blur). Albedo comes from the
buffer when present, else from the material. Work happens in at least float32 and the result has the
irradiance's dtype. Lengths of materials are in mm, depth in scene units, offsets in pixels via ``_units``.
"""

from __future__ import annotations

import functools
import math
from typing import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._kernels import GOLDEN_ANGLE, SeparableKernel, separable_kernel_from_profile, two_gaussian_kernel
from ._materials import BurleyMaterial, DirectionalLight, ProfileMaterial, STAParams, TwoGaussianMaterial
from ._profiles import BurleyProfile, burley_cdf, burley_inverse_ccdf, burley_R
from ._scene import Buffers, Camera, normals_from_depth, surface_mask, camera_positions
from ._slab import MediumMaterial, slab_transmittance
from ._units import px_per_mm

__all__ = ["translucency", "separable", "burley", "reference", "TECHNIQUES", "get_technique", "reference_radius_px",
           "ENERGY_CONSERVING", "thin_transmittance", "slab_transmittance", "TRANSLUCENCY_MODELS"]

ALBEDO_MODES = ("post", "pre_post")


# ------------------------------------------------------------------------------------------------------------------
# shared plumbing
# ------------------------------------------------------------------------------------------------------------------


def _work_dtype(dtype) -> jnp.dtype:
    return jnp.promote_types(dtype, jnp.float32)


def _check_albedo_mode(mode: str) -> None:
    if mode not in ALBEDO_MODES:
        raise ValueError(f"albedo_mode={mode!r} is not one of {ALBEDO_MODES}")


def _sss_mask(buffers: Buffers) -> Array:
    mask = surface_mask(buffers.depth)
    if buffers.material_id is not None:
        mask = mask & (buffers.material_id > 0)
    return mask


def _material_rows(buffers: Buffers, count: int) -> Array:
    """Row of the material table used by each pixel (id k -> row k-1; with one material every id uses it)."""
    if buffers.material_id is None or count == 1:
        return jnp.zeros(buffers.depth.shape, jnp.int32)
    return jnp.clip(buffers.material_id.astype(jnp.int32) - 1, 0, count - 1)


def _checked(x: Array, name: str, *, positive: bool = False) -> Array:
    """Value check that works under jit: NaN, inf and negative values trip it."""
    bad = ~(x > 0) if positive else ~(x >= 0)
    return eqx.error_if(x, bad | ~jnp.isfinite(x), f"{name} must be finite and {'> 0' if positive else '>= 0'}")


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
    albedo = jnp.clip(albedo.astype(dtype), 0.0, 1.0)
    # pixels that take no part hold nothing a neighbour could read: no NaN or inf depth, no stray irradiance
    e = jnp.where(valid[..., None], buffers.irradiance.astype(dtype), 0.0)
    depth = jnp.where(valid, buffers.depth.astype(dtype), 0.0)
    if albedo_mode == "pre_post":
        root = jnp.sqrt(albedo)
        e, albedo = e * root, root
    return _Prepared(irradiance=e, depth=depth, valid=valid, rows=rows, albedo_out=albedo)


def _finish(buffers: Buffers, prep: _Prepared, scattered: Array) -> Array:
    out = prep.albedo_out * scattered
    out = jnp.where(prep.valid[..., None], out, buffers.irradiance.astype(out.dtype))
    return out.astype(buffers.irradiance.dtype)


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


def _gather(flat: Array, height: int, width: int, y: Array, x: Array, *, interpolation: str) -> Array:
    """Interpolated fetch; outside the image counts as nothing (zero, so a validity channel in ``flat`` says how
    much of the fetch landed on valid pixels)."""
    parts = _corners(flat, height, width, y, x, interpolation=interpolation)
    return sum(val * w[..., None] for val, w in parts)


def _pack(e: Array, depth: Array, valid: Array) -> Array:
    """(H*W, 5): irradiance and depth zeroed where invalid (no inf * 0), and the validity itself."""
    v = valid.astype(e.dtype)
    z = jnp.where(valid, depth, 0.0)
    e = jnp.where(valid[..., None], e, 0.0)
    return jnp.concatenate([e, z[..., None], v[..., None]], axis=-1).reshape(-1, 5)


# ------------------------------------------------------------------------------------------------------------------
# Christensen–Burley: one pass of golden-angle spiral samples
# ------------------------------------------------------------------------------------------------------------------


def _safe_sqrt(x: Array) -> Array:
    """sqrt with a finite gradient at 0 (double where)."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def _burley_weight_kernel(x: Array) -> Array:
    """``(exp(-x) + exp(-x/3)) / x``: the Burley profile at ``r = x d`` up to the factor ``8 pi d^2`` that cancels in
    the per-channel normalisation. ``x = inf`` (d = 0 or no overlap) gives 0; x is never 0 here (r > 0)."""
    finite = jnp.isfinite(x) & (x > 0)
    xs = jnp.where(finite, x, 1.0)
    e3 = jnp.exp(-xs / 3)  # exp(-x) = e3^3: one exponential, not two
    return jnp.where(finite, e3 * (e3 * e3 + 1) / xs, 0.0)


# Footprint below which a pixel keeps its local shading (px): the paper's Fig. 1, scattering narrower than a pixel
# is invisible. The footprint is the radius holding 99% of the widest channel's energy, projected at the pixel.
MIN_FOOTPRINT_PX = 0.5

# radius holding 99% of a Burley profile's energy, in units of d (the footprint the skip and compaction test)
_BURLEY_R99 = float(np.asarray(burley_inverse_ccdf(np.float64(0.01), np.float64(1.0))))


@eqx.filter_jit
def _burley_impl(buffers: Buffers, material: BurleyMaterial, camera: Camera, samples: int, albedo_mode: str,
                 interpolation: str, capacity: int | None, min_footprint_px: float, weight_channels: int = 3,
                 truncate: bool = True) -> Array:
    dtype = _work_dtype(buffers.irradiance.dtype)
    d_table = _checked(material.d_mm.astype(dtype), "d_mm")
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
    rows_i = (idx // w).astype(dtype)
    cols_i = (idx % w).astype(dtype)
    # Samples beyond the image diagonal can never land: sample the profile truncated there (huge d clamps to the
    # image instead of losing every sample).
    diag_px = math.hypot(h, w)
    r_clip = jnp.where(ppm_c > 0, diag_px / jnp.where(ppm_c > 0, ppm_c, 1.0), jnp.inf)
    inside_fraction = jnp.where(dmax_c > 0, burley_cdf(jnp.minimum(r_clip, 1e30), dmax_c), 1.0)
    # channels with one d (grey materials) share one weight: the kernel is evaluated once, not per channel
    d_w = d_c[..., :weight_channels]
    ok_d = d_w > 0
    inv_d = jnp.where(ok_d, 1.0 / jnp.where(ok_d, d_w, 1.0), 0.0)

    # channel planes: every per-pixel quantity below is a 1D array over the pixels, which XLA vectorises along
    # (an (N, 3) layout leaves 3 lanes in the minor dimension)
    inv_d_planes = [inv_d[:, c] for c in range(weight_channels)]
    ok_d_planes = [ok_d[:, c] for c in range(weight_channels)]

    def body(i, acc):
        num, den = acc
        fi = jnp.asarray(i, dtype)
        if truncate:
            v = 1 - (fi + 0.5) / samples * inside_fraction  # stratified CCDF, truncated to the image
            rho = burley_inverse_ccdf(v, jnp.ones_like(v))  # radius in units of d_max
        else:  # no profile reaches past the image diagonal by more than rounding (decided on the host): every
            # pixel shares the sample radius, one scalar inverse CDF per sample, not one per pixel and sample
            rho = burley_inverse_ccdf(1 - (fi + 0.5) / samples, jnp.ones((), dtype))
        r_mm = rho * dmax_c
        off = r_mm * ppm_c
        theta = fi * GOLDEN_ANGLE
        # 1 / pdf of this sample (area density of the d_max profile at r), up to the per-pixel factor 8 pi d_max^2
        inv_pdf = rho / (jnp.exp(-rho) + jnp.exp(-rho / 3))
        # each pixel the fetch reads is its own point on the surface, with its own depth: weighting the corners
        # separately keeps light from leaking across a depth step through the interpolation
        num, den = list(num), list(den)
        for val, bw in _corners(flat, h, w, rows_i + off * jnp.sin(theta), cols_i + off * jnp.cos(theta),
                                interpolation=interpolation):
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
        return tuple(num), tuple(den)

    zeros = jnp.zeros(e_c.shape[:1], dtype)
    num, den = jax.lax.fori_loop(0, samples, body, ((zeros,) * 3, (zeros,) * weight_channels))
    num, den = jnp.stack(num, axis=-1), jnp.stack(den, axis=-1)
    ok = jnp.broadcast_to(den > 0, num.shape)
    result = jnp.where(ok, num / jnp.where(ok, den, 1.0), e_c)
    if capacity is None:
        scattered = result.reshape(h, w, 3)
    else:
        scattered = prep.irradiance.reshape(h * w, 3).at[idx].set(result, mode="drop").reshape(h, w, 3)
    scattered = jnp.where(active[..., None], scattered, prep.irradiance)
    return _finish(buffers, prep, scattered)


def _is_concrete(*trees) -> bool:
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(trees))


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
) -> Float[Array, "H W 3"]:
    """Screen-space Christensen–Burley normalised diffusion (one pass, ``samples`` spiral samples per pixel).

    Each sample's radius comes from stratified inverse-CDF sampling of the widest channel's profile (so one fetch
    serves R, G and B), its angle from the golden-angle spiral; it is placed in millimetres on the surface and
    projected with the pixel's depth. Its weight per channel is ``R_c(sqrt(r^2 + dz^2)) / pdf(r)`` (the depth
    difference dz makes light fall off across depth steps), and the weights are normalised per channel so flat
    lighting stays flat: energy is redistributed, not created. ``interpolation="bilinear"`` (default) makes the
    result continuous in d and depth (smooth for fitting); ``"nearest"`` fetches one pixel per sample.

    Cost follows the scene: pixels without SSS, and pixels whose footprint (the radius holding 99% of the widest
    channel's energy, in px) is below ``min_footprint_px`` (they keep their local shading, the paper's Fig. 1; 0
    disables that), take no samples. With concrete (not traced) inputs the active pixels are counted on the host and
    compacted into a buffer of the next power-of-two size (one compilation per size bucket), computed, and scattered
    back; ``compact=None`` (default) does so where the bucket holds under half the frame, ``True`` always, ``False``
    never. Under ``jit``/``vmap`` every pixel is computed (one compilation per shape). Compacted and dense results
    agree to rounding. Channels that share one d (a grey material, or every material grey) share one kernel
    evaluation per sample instead of three; the result is the same.
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
    return _burley_impl(buffers, material, camera, int(samples), albedo_mode, interpolation, capacity,
                        float(min_footprint_px), weight_channels, bool(truncate))


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


# ------------------------------------------------------------------------------------------------------------------
# Separable SSS: two 1D passes
# ------------------------------------------------------------------------------------------------------------------


def _kernel_table(material, taps: int, dtype) -> tuple[Array, Array]:
    """Offsets (M, n) in mm and weights (M, n, 3) of each material's separable kernel."""
    if isinstance(material, TwoGaussianMaterial):
        w = jnp.clip(material.w.astype(dtype), 0.0, 1.0)
        s_near = _checked(material.sigma_near_mm.astype(dtype), "sigma_near_mm")
        s_far = _checked(material.sigma_far_mm.astype(dtype), "sigma_far_mm")
        kernels = jax.vmap(lambda a, b, c: two_gaussian_kernel(a, b, c, taps=taps))(w, s_near, s_far)
    elif isinstance(material, BurleyMaterial):
        d = _checked(material.d_mm.astype(dtype), "d_mm")
        kernels = jax.vmap(lambda row: separable_kernel_from_profile(BurleyProfile(row), taps=taps))(d)
    elif isinstance(material, ProfileMaterial):
        k = separable_kernel_from_profile(material.profile, taps=taps)
        kernels = SeparableKernel(offsets_mm=k.offsets_mm[None].astype(dtype), weights=k.weights[None].astype(dtype))
    else:
        raise TypeError(
            "separable needs a TwoGaussianMaterial, BurleyMaterial or ProfileMaterial, got " + type(material).__name__
        )
    return kernels.offsets_mm.astype(dtype), kernels.weights.astype(dtype)


# Pixel-scale levels of the separable pass: each level is one shifted-slice pass at a constant reach; a pixel
# blends the two levels that bracket its own reach (in log scale), so the result stays continuous in d and depth.
SCALE_LEVELS = 4


def _unit_tap_offsets(taps: int) -> np.ndarray:
    """The tap pattern in units of the kernel's reach (``tap_offsets`` with range 1): every kernel shares it."""
    o = np.linspace(-1.0, 1.0, taps) if taps > 1 else np.zeros(1)
    u = np.sign(o) * np.abs(o) ** 2.0
    order = [taps // 2] + [i for i in range(taps) if i != taps // 2]
    return u[order]


def _safe_log(x: Array) -> Array:
    pos = x > 0
    return jnp.where(pos, jnp.log(jnp.where(pos, x, 1.0)), 0.0)


def _separable_level(fetch: Callable[[Array], tuple[Array, Array, Array]], e: Array, z: Array, reach_px: Array,
                     inv_reach_mm: Array, tap_weight: Callable[[Array | int], Array], weight_sum: Array,
                     unit_offsets: Array, taps_per_chunk: int, mm_per_unit: Array, limit: float, follow_surface: bool,
                     interpolation: str) -> Array:
    """One 1D pass at one constant reach ``reach_px`` (a scalar) over a band of rows: ``fetch(start)`` returns the
    padded planes (irradiance times validity, depth times validity, validity) shifted by ``start`` pixels along the
    pass, so every tap is a constant shift. The taps are unrolled ``taps_per_chunk`` at a time into one expression,
    which XLA fuses into one loop over the band (each pixel reads a chunk's taps and adds them to its result at once);
    a loop runs the chunks, so the compile time and the fusions' size stay bounded as the taps grow.
    ``unit_offsets`` has a whole number of chunks (padding taps have weight 0).

    Each pixel q a tap reads (one for "nearest"; two for "linear", with weights 1 - f and f) adds
    ``w f keep_q (e_q - e)`` to ``e sum(w)``, which is ``sum(w (sum_q f keep_q e_q + (1 - sum_q f keep_q) e))``: the
    tap counts as far as it landed on valid pixels at a similar depth, and as the centre for the rest. No division
    and no transcendental per tap, so nothing stops XLA from fusing a chunk whole."""
    scale = mm_per_unit * inv_reach_mm  # depth difference (scene units) at which a fetch stops counting

    def chunk(c, acc):
        for j in range(taps_per_chunk):
            i = c * taps_per_chunk + j
            # offsets beyond the image land in the zero padding: nothing valid there, the tap counts as the centre
            off = jnp.clip(unit_offsets[i] * reach_px, -limit, limit)
            if interpolation == "nearest":
                corners = [(jnp.round(off).astype(jnp.int32), None)]
            else:
                x0 = jnp.floor(off)
                f = off - x0
                start = x0.astype(jnp.int32)
                corners = [(start, 1 - f), (start + 1, f)]
            term = 0.0
            for start, frac in corners:
                ev, zv, vv = fetch(start)
                # Jimenez's "follow the surface", per fetched pixel: it counts less as its depth differs from the
                # centre's (none at the kernel's reach); invalid or off-image pixels count as the centre. v is 0 or
                # 1, so keep = v (1 - clip(|z_q - z| scale)) = max(v - |v z_q - v z| scale, 0): no division
                keep = jnp.maximum(vv - jnp.abs(zv - vv * z) * scale, 0.0) if follow_surface else vv
                keep = keep if frac is None else frac * keep
                term = term + keep[None] * (ev - e)
            acc = acc + tap_weight(i) * term
        return acc

    chunks = unit_offsets.shape[0] // taps_per_chunk
    if chunks == 1:
        return chunk(0, e * weight_sum)
    return jax.lax.fori_loop(0, chunks, chunk, e * weight_sum)


def tap_chunks(taps: int) -> tuple[int, int]:
    """(chunks, taps per chunk) of a separable pass: as few chunks as keep each at most ``_TAPS_PER_FUSION`` taps,
    the taps spread evenly over them."""
    chunks = -(-taps // _TAPS_PER_FUSION)
    return chunks, -(-taps // chunks)


# Taps fused into one loop over a band. Unrolling every tap of a wide kernel into one expression makes XLA's CPU
# fusion fall apart (65 taps in one: 8x slower than 33 at 256x256, 14x at 1920x1080); chunks of at most this many
# keep it whole (65 taps as two chunks of 33: 1.8x the time of 33 at 640x360).
_TAPS_PER_FUSION = 33


def _band_rows(height: int, width: int) -> int:
    """Rows per band of a pass: at least ``_MIN_BANDS`` bands (finer cost-following), and few enough pixels per band
    that the rows a tap reads stay in the L2 cache (1920x1080: 18 rows, ~9% faster than 68), at least 8 rows each."""
    return max(8, min(-(-height // _MIN_BANDS), -(-_BAND_PIXELS // width)))


_MIN_BANDS = 16
_BAND_PIXELS = 1 << 15


def _separable_pass(e: Array, z: Array, valid: Array, level_weights: Array, level_reach_px: Array, skip: Array,
                    onehot: Array | None, w_table: Array, inv_reach_mm: Array, unit_offsets: Array,
                    mm_per_unit: Array, follow_surface: bool, interpolation: str,
                    rows_per_band: int | None = None, axis: int = 2) -> Array:
    """One 1D pass of planar ``e (3, H, W)`` along ``axis``: 2 horizontal, 1 vertical (no transposes: both read
    whole rows). The levels' shifted-slice passes are blended per pixel by ``level_weights (L, H, W)``; ``skip``
    pixels keep their own value.

    The frame is cut into bands of rows (independent in either pass: a band reads its taps from the whole padded
    frame) and each band computes only the levels its own pixels use (a band without SSS pixels computes none): the
    cost follows the scene's coverage and depth range. A loop writes each band's rows in place into the output (the
    last band ends at the last row, overlapping the one before where the height is no multiple of the band): no
    padding rows and no reassembly copy. Tap weights: ``w_table (M, 3, n)`` per material, chosen per pixel by
    ``onehot (M, H, W)`` (``None`` for one material)."""
    if axis not in (1, 2):
        raise ValueError(f"axis must be 1 (vertical) or 2 (horizontal), got {axis!r}")
    _, h, w = e.shape
    rows_per_band = min(rows_per_band or _band_rows(h, w), h)
    bands = -(-h // rows_per_band)  # the last band ends at the last row (it may overlap the one before: same values)
    pad = (w if axis == 2 else h) + 2  # every clipped offset lands inside the padding
    v = valid.astype(e.dtype)
    pad_width = [(0, 0), (pad, pad)] if axis == 2 else [(pad, pad), (0, 0)]
    pad_fetched = lambda a: jnp.pad(a, [(0, 0)] * (a.ndim - 2) + pad_width)
    ev_pad, z_pad, v_pad = pad_fetched(e * v[None]), pad_fetched(z * v), pad_fetched(v)
    planes = {"e": e, "z": z, "lw": level_weights, "inv": inv_reach_mm, "skip": skip}
    if onehot is not None:
        planes["onehot"] = onehot
    weight_sums = jnp.sum(w_table, axis=-1)  # (M, 3)
    chunks, per_chunk = tap_chunks(unit_offsets.shape[0])
    extra_taps = chunks * per_chunk - unit_offsets.shape[0]  # padding taps: weight 0 at offset 0 (the centre: adds 0)
    unit_offsets = jnp.pad(unit_offsets, (0, extra_taps))
    w_table = jnp.pad(w_table, [(0, 0), (0, 0), (0, extra_taps)])

    def band(k, out):
        row0 = jnp.minimum(k * rows_per_band, h - rows_per_band).astype(jnp.int32)
        b = {name: jax.lax.dynamic_slice_in_dim(a, row0, rows_per_band, axis=a.ndim - 2) for name, a in planes.items()}

        def fetch(start):
            o = jnp.zeros((), jnp.int32)  # index arguments of one type (int64 under x64 otherwise)
            row, col = (row0, pad + start) if axis == 2 else (pad + row0 + start, o)
            return (jax.lax.dynamic_slice(ev_pad, (o, row, col), (3, rows_per_band, w)),
                    jax.lax.dynamic_slice(z_pad, (row, col), (rows_per_band, w)),
                    jax.lax.dynamic_slice(v_pad, (row, col), (rows_per_band, w)))

        if onehot is None:
            tap_weight = lambda i: w_table[0, :, i][:, None, None]
            weight_sum = weight_sums[0][:, None, None]
        else:
            per_pixel = lambda table: sum(b["onehot"][m][None] * table[m][:, None, None] for m in range(len(w_table)))
            tap_weight = lambda i: per_pixel(w_table[:, :, i])
            weight_sum = per_pixel(weight_sums)

        def level(j, acc):
            lw = b["lw"][j]
            run = lambda: _separable_level(fetch, b["e"], b["z"], level_reach_px[j], b["inv"], tap_weight, weight_sum,
                                           unit_offsets, per_chunk, mm_per_unit, pad - 1.0, follow_surface,
                                           interpolation)
            return acc + lw[None] * jax.lax.cond(jnp.any(lw > 0), run, lambda: jnp.zeros_like(b["e"]))

        # a loop, not unrolled: the compile time does not grow with the number of levels
        result = jax.lax.fori_loop(0, level_reach_px.shape[0], level, jnp.zeros_like(b["e"]))
        result = jnp.where(b["skip"][None], b["e"], result)
        return jax.lax.dynamic_update_slice_in_dim(out, result, row0, axis=1)  # in place: the loop owns ``out``

    return jax.lax.fori_loop(0, bands, band, e)


@eqx.filter_jit
def _separable_impl(buffers: Buffers, material, camera: Camera, taps: int, albedo_mode: str, follow_surface: bool,
                    interpolation: str, scale_levels: int, min_footprint_px: float,
                    kernel_groups: tuple[int, ...] | None = None) -> Array:
    dtype = _work_dtype(buffers.irradiance.dtype)
    prep = _prepare(buffers, material.albedo, albedo_mode, dtype)
    rows, kernel_material = prep.rows, material
    if kernel_groups is not None:  # materials with one kernel share it: one kernel, one weight term per group
        first = np.asarray([kernel_groups.index(g) for g in range(max(kernel_groups) + 1)])
        kernel_material = jax.tree.map(lambda a: a[first], material)  # each distinct kernel built once
        rows = jnp.asarray(kernel_groups, jnp.int32)[rows]
    offsets, weights = _kernel_table(kernel_material, taps, dtype)  # (K, n) mm, (K, n, 3)
    mm_per_unit = camera.mm_per_unit.astype(dtype)
    ppm = px_per_mm(prep.depth, focal_px=camera.focal_px.astype(dtype), mm_per_unit=mm_per_unit)
    ppm = jnp.where(prep.valid, ppm, 0.0)
    table_reach_mm = jnp.max(jnp.abs(offsets), axis=-1)  # (M,): every kernel is its reach times one tap pattern
    count = offsets.shape[0]
    onehot = [(rows == m).astype(dtype) for m in range(count)] if count > 1 else None
    per_pixel = lambda table: table[0] if count == 1 else sum(onehot[m] * table[m] for m in range(count))
    reach_mm = jnp.broadcast_to(per_pixel(table_reach_mm), ppm.shape)  # (H, W)
    reach_px = reach_mm * ppm
    ok_reach = reach_mm > 0
    inv_reach_mm = jnp.where(ok_reach, 1.0 / jnp.where(ok_reach, reach_mm, 1.0), 0.0)
    # pixels whose footprint is below min_footprint_px keep their local shading: no pass runs for them
    active = prep.valid & (reach_px >= min_footprint_px) & (reach_px > 0)
    skip = ~active
    # levels: geometric between the smallest and the largest reach among active pixels
    log_r = _safe_log(reach_px)
    big = jnp.asarray(jnp.finfo(dtype).max, dtype)
    lo = jnp.min(jnp.where(active, log_r, big))
    hi = jnp.max(jnp.where(active, log_r, -big))
    any_active = jnp.any(active)
    lo, hi = jnp.where(any_active, lo, 0.0), jnp.where(any_active, hi, 0.0)
    span = hi - lo
    ok_span = span > 0
    nlev = scale_levels
    t = jnp.where(ok_span, (log_r - lo) / jnp.where(ok_span, span, 1.0), 0.0) * (nlev - 1)
    t = jnp.clip(t, 0.0, nlev - 1)
    levels = jnp.arange(nlev, dtype=dtype)
    level_weights = jnp.maximum(0.0, 1 - jnp.abs(t[None] - levels[:, None, None]))
    level_weights = jnp.where(active[None], level_weights, 0.0)
    level_reach_px = jnp.exp(lo + span * levels / max(nlev - 1, 1))
    level_reach_px = jnp.where(any_active, level_reach_px, 0.0)
    unit_offsets = jnp.asarray(_unit_tap_offsets(taps), dtype)
    w_table = jnp.moveaxis(weights, -1, 1)  # (M, 3, n)
    onehot_planes = None if count == 1 else jnp.stack(onehot)  # (M, H, W)
    common = dict(unit_offsets=unit_offsets, mm_per_unit=mm_per_unit, follow_surface=follow_surface,
                  interpolation=interpolation)
    e = jnp.moveaxis(prep.irradiance, -1, 0)  # planar (3, H, W): the fused loops run along rows
    for axis in (2, 1):  # horizontal, then vertical
        e = _separable_pass(e, prep.depth, prep.valid, level_weights, level_reach_px, skip, onehot_planes, w_table,
                            inv_reach_mm, axis=axis, **common)
    return _finish(buffers, prep, jnp.moveaxis(e, 0, -1))


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
    gathers). The reach in px varies with depth and material; it is quantised into ``scale_levels`` geometric levels
    between the frame's smallest and largest reach, and each pixel blends the two levels bracketing its own reach
    (exact where every pixel has the same reach; levels no pixel uses are skipped). Pixels whose footprint (the radius
    holding 99% of the widest channel's energy, in px) is below ``min_footprint_px`` keep their local shading
    (``albedo * irradiance``, the paper's Fig. 1); 0 disables that. Several materials in one frame cost one pass;
    materials that share a kernel (differing only in albedo) share its table row and per-pixel weight term.
    """
    _check_albedo_mode(albedo_mode)
    if interpolation not in ("linear", "nearest"):
        raise ValueError(f"interpolation={interpolation!r} is not one of ('linear', 'nearest')")
    if not isinstance(taps, (int, np.integer)) or taps < 1 or taps % 2 == 0:
        raise ValueError(f"taps must be an odd positive integer, got {taps!r}")
    if not isinstance(scale_levels, (int, np.integer)) or scale_levels < 1:
        raise ValueError(f"scale_levels must be a positive integer, got {scale_levels!r}")
    if not (float(min_footprint_px) >= 0):
        raise ValueError(f"min_footprint_px must be >= 0, got {min_footprint_px!r}")
    mode = "bilinear" if interpolation == "linear" else "nearest"
    return _separable_impl(buffers, material, camera, int(taps), albedo_mode, bool(follow_surface), mode,
                           int(scale_levels), float(min_footprint_px), kernel_groups(material))


def kernel_groups(material) -> tuple[int, ...] | None:
    """Host side: for a table of several materials of which some share one separable kernel (the same d, or the
    same two-Gaussian w and sigmas; the albedo may differ), the group of each material (groups numbered in order of
    first appearance), so ``separable`` builds and weights each distinct kernel once; ``None`` where every kernel is
    distinct, for one material, or for traced parameters."""
    if isinstance(material, BurleyMaterial):
        params = [material.d_mm]
    elif isinstance(material, TwoGaussianMaterial):
        params = [material.w, material.sigma_near_mm, material.sigma_far_mm]
    else:
        return None
    if not _is_concrete(params) or np.ndim(params[0]) < 2 or np.shape(params[0])[0] < 2:
        return None
    key = np.concatenate([np.asarray(p).reshape(np.shape(params[0])[0], -1) for p in params], axis=1)
    groups: dict[bytes, int] = {}
    out = tuple(groups.setdefault(row.tobytes(), len(groups)) for row in key)
    return out if len(groups) < len(out) else None


# ------------------------------------------------------------------------------------------------------------------
# Reference: dense convolution with the exact, pixel-integrated profile
# ------------------------------------------------------------------------------------------------------------------

_THETA_NODES, _THETA_WEIGHTS = np.polynomial.legendre.leggauss(16)


def _profile_functions(material, d_pix: Array | None) -> tuple[Callable, Callable]:
    """(radial(r (H,W)) -> (H,W,3), cdf(r (H,W)) -> (H,W,3)) for the pixel's own material."""
    if isinstance(material, BurleyMaterial):
        return (lambda r: burley_R(r[..., None], d_pix), lambda r: burley_cdf(r[..., None], d_pix))
    profile = material.profile
    return profile.radial, profile.cdf


def reference_radius_px(buffers: Buffers, material, camera: Camera, *, energy: float = 0.999, cap: int = 96) -> int:
    """Window radius (px, host side) holding ``energy`` of the widest profile at the nearest SSS pixel, capped."""
    valid = np.asarray(_sss_mask(buffers))
    if not valid.any():
        return 1
    depth = np.asarray(buffers.depth, dtype=np.float64)[valid]
    ppm_max = float(camera.focal_px) / (float(np.min(depth)) * float(camera.mm_per_unit))
    if isinstance(material, BurleyMaterial):
        radius_mm = float(np.max(np.asarray(burley_inverse_ccdf(1 - energy, np.asarray(material.d_mm, np.float64)))))
    else:
        radius_mm = float(np.max(np.asarray(material.profile.radius_for_energy(energy))))
    return int(max(1, min(cap, math.ceil(radius_mm * ppm_max))))


@eqx.filter_jit
def _reference_impl(buffers: Buffers, material, camera: Camera, radius_px: int, albedo_mode: str,
                    near_subsamples: int) -> Array:
    dtype = _work_dtype(buffers.irradiance.dtype)
    prep = _prepare(buffers, material.albedo, albedo_mode, dtype)
    h, w = buffers.depth.shape
    mm_per_unit = camera.mm_per_unit.astype(dtype)
    ppm = px_per_mm(prep.depth, focal_px=camera.focal_px.astype(dtype), mm_per_unit=mm_per_unit)
    ppm = jnp.where(prep.valid, ppm, 0.0)
    pixel_mm = jnp.where(ppm > 0, 1.0 / jnp.where(ppm > 0, ppm, 1.0), 0.0)  # side of a pixel on the surface, mm
    d_pix = None
    if isinstance(material, BurleyMaterial):
        d_table = _checked(material.d_mm.astype(dtype), "d_mm")
        d_pix = jnp.where(prep.valid[..., None], d_table[prep.rows], 0.0)
    radial, cdf = _profile_functions(material, d_pix)

    # centre pixel: exact mass of the profile over the square of half-side a, with the 1/r peak integrated
    # analytically through the CDF: (4/pi) int_0^{pi/4} CDF(a / cos t) dt
    a = 0.5 * pixel_mm
    nodes = jnp.asarray(_THETA_NODES, dtype)
    t = (nodes + 1) * (math.pi / 8)
    tw = jnp.asarray(_THETA_WEIGHTS, dtype) * (math.pi / 8)
    centre_mass = sum(tw[k] * cdf(a / jnp.cos(t[k])) for k in range(t.shape[0])) * (4 / math.pi)
    e = prep.irradiance
    centre_w = jnp.where(prep.valid[..., None], centre_mass, 0.0)
    num, den = centre_w * e, centre_w

    k = radius_px
    pad = lambda x: jnp.pad(x, [(k, k), (k, k)] + [(0, 0)] * (x.ndim - 2))
    e_pad = pad(e * prep.valid[..., None])
    z_pad = pad(jnp.where(prep.valid, prep.depth, 0.0))
    v_pad = pad(prep.valid.astype(dtype))

    def neighbour_weight(dy, dx, sub: int):
        """Mass of the profile over neighbour pixel (dy, dx): sub x sub midpoint rule on the surface, 3D distance."""
        z_q = jax.lax.dynamic_slice(z_pad, (k + dy, k + dx), (h, w))
        v_q = jax.lax.dynamic_slice(v_pad, (k + dy, k + dx), (h, w))
        e_q = jax.lax.dynamic_slice(e_pad, (k + dy, k + dx, 0), (h, w, 3))
        dz_mm = jnp.where(v_q > 0, (z_q - prep.depth) * mm_per_unit, 0.0)
        mass = 0.0
        for sy in range(sub):
            for sx in range(sub):
                oy = dy + (sy + 0.5) / sub - 0.5
                ox = dx + (sx + 0.5) / sub - 0.5
                r2 = (oy * oy + ox * ox) * pixel_mm * pixel_mm + dz_mm * dz_mm
                mass = mass + radial(_safe_sqrt(r2))
        mass = mass * (pixel_mm * pixel_mm / (sub * sub))[..., None]
        wgt = jnp.where((v_q > 0)[..., None], mass, 0.0)
        return wgt, e_q

    def ring(acc, inner: int, outer: int, sub: int):
        """Add the pixels with inner < max(|dy|, |dx|) <= outer, each by a sub x sub midpoint rule."""
        side = 2 * outer + 1

        def body(idx, acc):
            num, den = acc
            dy = idx // side - outer
            dx = idx % side - outer
            skip = (jnp.abs(dy) <= inner) & (jnp.abs(dx) <= inner)
            wgt, e_q = neighbour_weight(dy, dx, sub)
            wgt = jnp.where(skip, 0.0, wgt)
            return num + wgt * e_q, den + wgt

        return jax.lax.fori_loop(0, side * side, body, acc)

    # the profile changes fastest across the nearest pixels: they get finer rules than the far field
    tiers = [(0, min(k, 2), near_subsamples), (2, min(k, 6), 2), (6, k, 1)]
    acc = (num, den)
    for inner, outer, sub in tiers:
        if outer > inner:
            acc = ring(acc, inner, outer, sub)
    num, den = acc
    ok = den > 0
    scattered = jnp.where(ok, num / jnp.where(ok, den, 1.0), e)
    return _finish(buffers, prep, scattered)


def reference(
    buffers: Buffers,
    material: BurleyMaterial | ProfileMaterial,
    camera: Camera,
    *,
    radius_px: int | None = None,
    albedo_mode: str = "post",
    near_subsamples: int = 6,
) -> Float[Array, "H W 3"]:
    """Ground truth: every pixel within ``radius_px`` contributes the exact mass of the profile over its footprint.

    The centre pixel's mass is integrated through the profile's CDF (so r -> 0 is finite); neighbours use a midpoint
    rule (``near_subsamples``^2 points within two pixels, 2x2 within six, one beyond) at the 3D distance (depth difference
    included); weights are normalised over valid pixels. ``radius_px`` defaults to the radius holding 99.9% of the
    widest channel's energy at the nearest SSS pixel (host side; pass it explicitly under ``jit``). Slow by design.
    """
    _check_albedo_mode(albedo_mode)
    if not isinstance(material, (BurleyMaterial, ProfileMaterial)):
        raise TypeError(f"reference needs a BurleyMaterial or ProfileMaterial, got {type(material).__name__}")
    if radius_px is None:
        radius_px = reference_radius_px(buffers, material, camera)
    if not isinstance(radius_px, (int, np.integer)) or radius_px < 0:
        raise ValueError(f"radius_px must be a non-negative integer, got {radius_px!r}")
    return _reference_impl(buffers, material, camera, int(radius_px), albedo_mode, int(near_subsamples))


# ------------------------------------------------------------------------------------------------------------------
# Simple translucency approximation
# ------------------------------------------------------------------------------------------------------------------


def _safe_pow(x: Array, p: Array) -> Array:
    """``x^p`` for x >= 0 with ``0^0 = 1`` and finite gradients in x and p."""
    pos = x > 0
    xs = jnp.where(pos, x, 1.0)
    return jnp.where(pos, jnp.exp(p * jnp.log(xs)), jnp.where(p == 0, 1.0, 0.0))


def sta_term(normal: Array, view: Array, light: DirectionalLight, params: STAParams, thickness_mm: Array) -> Array:
    """Per-pixel translucency light ``light * t * (s_T max(0, V . -L_T)^p_T + a_T)``, ``(H, W, 3)`` (before albedo).

    ``L_T = norm(L + d_T N)`` (Barré-Brisebois & Bouchard 2011; the paper's Sec. 3.1); ``t = exp(-thickness/t_mm)``.
    """
    dtype = normal.dtype
    l = light.direction.astype(dtype)
    lt = l.reshape(1, 1, 3) + params.distortion.astype(dtype) * normal
    norm = jnp.linalg.norm(lt, axis=-1, keepdims=True)
    ok = norm > 1e-12
    lt = jnp.where(ok, lt / jnp.where(ok, norm, 1.0), 0.0)
    cos_back = jnp.clip(jnp.sum(view * -lt, axis=-1), 0.0, 1.0)
    power = _checked(params.power.astype(dtype), "STA power")
    t_dir = params.scale.astype(dtype).reshape(1, 1, 3) * _safe_pow(cos_back, power)[..., None]
    scale_mm = _checked(params.thickness_mm.astype(dtype), "STA thickness_mm", positive=True)
    ratio = thickness_mm[..., None] / scale_mm.reshape(1, 1, 3)
    atten = jnp.where(jnp.isfinite(ratio), jnp.exp(-jnp.where(jnp.isfinite(ratio), ratio, 0.0)), 0.0)
    return light.colour.astype(dtype).reshape(1, 1, 3) * atten * (t_dir + params.ambient.astype(dtype).reshape(1, 1, 3))


def _thickness_mm(buffers: Buffers, thickness: Array | None, camera: Camera, shape: tuple[int, ...], dtype) -> Array:
    """Per-pixel thickness in mm: the thickness buffer, else the constant ``thickness`` (scene units), else 0."""
    if buffers.thickness is not None:
        thick_units = buffers.thickness.astype(dtype)
    elif thickness is not None:
        thick_units = jnp.broadcast_to(jnp.asarray(thickness, dtype), shape)
    else:
        thick_units = jnp.zeros(shape, dtype)
    return thick_units * camera.mm_per_unit.astype(dtype)


@eqx.filter_jit
def _translucency_impl(buffers: Buffers, params: STAParams, camera: Camera, light: DirectionalLight,
                       thickness: Array | None, material_albedo: Array) -> Array:
    dtype = _work_dtype(buffers.irradiance.dtype)
    prep = _prepare(buffers, material_albedo, "post", dtype)
    normal = buffers.normal.astype(dtype) if buffers.normal is not None else normals_from_depth(prep.depth, camera)
    pos = camera_positions(prep.depth, camera)
    view = -pos / jnp.linalg.norm(pos, axis=-1, keepdims=True)
    thick_mm = _thickness_mm(buffers, thickness, camera, prep.depth.shape, dtype)
    added = sta_term(normal, view, light, params, thick_mm)
    out = prep.albedo_out * (prep.irradiance + added)
    out = jnp.where(prep.valid[..., None], out, buffers.irradiance.astype(dtype))
    return out.astype(buffers.irradiance.dtype)


def thin_transmittance(thickness_mm: Array, d_mm: Array) -> Array:
    """Thin-object transmittance of the normalised Burley profile: ``(exp(-t/d) + 3 exp(-t/(3d))) / 4``.

    The fraction of the profile's energy beyond radius t, ``1 - CDF(t)``, i.e. the integral of the profile over a
    plane at distance t (Unity HDRP ``ComputeTransmittanceDisney`` in ``SubsurfaceScattering.hlsl``, which HDRP
    multiplies by ``0.25 * transmissionTint`` and later by the albedo; UE5 ``GetBurleyTransmissionProfile``:
    ``0.25 A (exp(-s r) + 3 exp(-s r / 3))`` with ``r = t / dmfp``). Elementwise in (t, d), both in mm; d = 0 gives 0
    for t > 0. See docs/engines.md for how it compares with Monte Carlo slab transmission.
    """
    return 1.0 - burley_cdf(thickness_mm, d_mm)


def _thin_model(thickness_mm: Array, albedo: Array, d_mm: Array) -> Array:
    return thin_transmittance(thickness_mm, d_mm)  # the profile's CCDF: the albedo plays no part


# transmittance T(thickness_mm, medium albedo, d_mm) of each physically based model, elementwise per channel
_TRANSMITTANCE: dict[str, Callable[[Array, Array, Array], Array]] = {"thin": _thin_model, "slab": slab_transmittance}


@eqx.filter_jit
def _transmission_impl(buffers: Buffers, material: BurleyMaterial, camera: Camera, light: DirectionalLight,
                       thickness: Array | None, model: str, medium: MediumMaterial | None = None) -> Array:
    """``albedo * (irradiance + light * T * max(0, -N . L))`` ("thin", HDRP's convention), or
    ``albedo * irradiance + light * T * max(0, -N . L)`` ("slab": T already holds all of the medium's absorption; T of
    ``medium`` where given)."""
    dtype = _work_dtype(buffers.irradiance.dtype)
    prep = _prepare(buffers, material.albedo, "post", dtype)
    normal = buffers.normal.astype(dtype) if buffers.normal is not None else normals_from_depth(prep.depth, camera)
    thick_mm = jnp.maximum(_thickness_mm(buffers, thickness, camera, prep.depth.shape, dtype), 0.0)
    d = _checked(material.d_mm.astype(dtype), "d_mm")[prep.rows]  # (H, W, 3)
    # the medium is the material's (its A and d per material id), not the albedo texture's, which only tints
    medium_albedo = jnp.clip(material.albedo.astype(dtype), 0.0, 1.0)[prep.rows]
    t = jnp.where(jnp.isfinite(thick_mm), thick_mm, 0.0)[..., None]
    T = _TRANSMITTANCE[model](t, medium_albedo, d) if medium is None else medium.transmittance(t[..., 0], prep.rows)
    transmitted = jnp.where(jnp.isfinite(thick_mm)[..., None], T, 0.0)
    # light reaching the back face: the cosine between the back-facing normal and the light
    back_cos = jnp.clip(jnp.sum(-normal * light.direction.astype(dtype).reshape(1, 1, 3), axis=-1), 0.0, 1.0)
    added = light.colour.astype(dtype).reshape(1, 1, 3) * transmitted * back_cos[..., None]
    out = prep.albedo_out * (prep.irradiance + (added if model == "thin" else 0.0)) + (added if model == "slab" else 0.0)
    out = jnp.where(prep.valid[..., None], out, buffers.irradiance.astype(dtype))
    return out.astype(buffers.irradiance.dtype)


TRANSLUCENCY_MODELS = ("sta", "thin", "slab")


def translucency(
    buffers: Buffers,
    params: STAParams | BurleyMaterial | MediumMaterial,
    camera: Camera,
    light: DirectionalLight,
    *,
    albedo: Array | None = None,
    thickness: float | None = None,
    model: str = "sta",
) -> Float[Array, "H W 3"]:
    """Back-lighting through thin parts: ``albedo * (irradiance + transmitted light)`` on SSS pixels.

    ADDS light (not energy conserving): the back-light through the object's thickness is added on top of local
    diffuse shading. Thickness (scene units) comes from ``buffers.thickness``, else the constant ``thickness``, else
    0 (paper-thin). Normals come from ``buffers.normal`` (camera space) or are derived from depth.

    - ``model="sta"`` (default): the simple translucency approximation with ``STAParams``; ``albedo (3,)`` is used
      where the buffers carry none (default white).
    - ``model="thin"``: the HDRP engine model, thin-object transmission as HDRP's thin mode computes it:
      ``albedo * light * thin_transmittance(thickness_mm, d) * max(0, -N . L)`` with ``params`` a ``BurleyMaterial``
      (its d per material id, its albedo where the buffers carry none). HDRP wraps the cosine; this uses the plain
      clamped cosine.
    - ``model="slab"``: slab transport, ``light * T * max(0, -N . L)`` added to ``albedo * irradiance``: T, the
      fraction of a normal back light leaving the front face, already holds all absorption (no albedo factor). With
      ``params`` a ``MediumMaterial`` (a preset that carries its medium: ``load_preset(...).medium``) T is that of the
      measured medium with its boundaries (``_slab.MediumMaterial``); with a ``BurleyMaterial``,
      ``slab_transmittance(thickness_mm, A, d)``, the index-matched medium rebuilt from A and d.
    """
    if model not in TRANSLUCENCY_MODELS:
        raise ValueError(f"model={model!r} is not one of {TRANSLUCENCY_MODELS}")
    if not isinstance(light, DirectionalLight):
        raise TypeError(f"translucency needs a DirectionalLight, got {type(light).__name__}")
    if model in _TRANSMITTANCE:
        medium = params if model == "slab" and isinstance(params, MediumMaterial) else None
        params = medium.burley if medium is not None else params
        if not isinstance(params, BurleyMaterial):
            raise TypeError(f"translucency(model={model!r}) needs a BurleyMaterial, got {type(params).__name__}")
        return _transmission_impl(buffers, params, camera, light, thickness, model, medium)
    if not isinstance(params, STAParams):
        raise TypeError(f"translucency needs STAParams, got {type(params).__name__}")
    table = jnp.ones((1, 3), buffers.irradiance.dtype) if albedo is None else jnp.reshape(jnp.asarray(albedo), (-1, 3))
    return _translucency_impl(buffers, params, camera, light, thickness, table)


TECHNIQUES: dict[str, Callable] = {
    "sta": translucency,
    "separable": separable,
    "burley": burley,
    "reference": reference,
}

# Which techniques redistribute light (True) and which add it (False): the report shows this.
ENERGY_CONSERVING = {"sta": False, "separable": True, "burley": True, "reference": True}


def get_technique(name: str) -> Callable:
    """The technique registered under ``name``; the error lists the valid names."""
    try:
        return TECHNIQUES[name]
    except KeyError:
        raise ValueError(f"unknown technique {name!r}; valid techniques: {', '.join(TECHNIQUES)}") from None
