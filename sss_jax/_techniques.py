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
from ._units import px_per_mm

__all__ = ["translucency", "separable", "burley", "reference", "TECHNIQUES", "get_technique", "reference_radius_px",
           "ENERGY_CONSERVING"]

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


def _unpack(fetched: Array) -> tuple[Array, Array, Array]:
    """Validity-normalised irradiance and depth of a fetch, and the fraction of it that was valid."""
    vq = fetched[..., 4]
    ok = vq > 1e-6
    inv = jnp.where(ok, 1.0 / jnp.where(ok, vq, 1.0), 0.0)
    return fetched[..., :3] * inv[..., None], fetched[..., 3] * inv, jnp.where(ok, vq, 0.0)


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
    return jnp.where(finite, (jnp.exp(-xs) + jnp.exp(-xs / 3)) / xs, 0.0)


@eqx.filter_jit
def _burley_impl(buffers: Buffers, material: BurleyMaterial, camera: Camera, samples: int, albedo_mode: str,
                 interpolation: str) -> Array:
    dtype = _work_dtype(buffers.irradiance.dtype)
    d_table = _checked(material.d_mm.astype(dtype), "d_mm")
    prep = _prepare(buffers, material.albedo, albedo_mode, dtype)
    h, w = buffers.depth.shape
    mm_per_unit = camera.mm_per_unit.astype(dtype)
    d_pix = jnp.where(prep.valid[..., None], d_table[prep.rows], 0.0)  # (H, W, 3)
    d_max = jnp.max(d_pix, axis=-1)
    ppm = px_per_mm(prep.depth, focal_px=camera.focal_px.astype(dtype), mm_per_unit=mm_per_unit)
    ppm = jnp.where(prep.valid, ppm, 0.0)
    # Samples beyond the image diagonal can never land: sample the profile truncated there (huge d clamps to the
    # image instead of losing every sample).
    diag_px = math.hypot(h, w)
    r_clip = jnp.where(ppm > 0, diag_px / jnp.where(ppm > 0, ppm, 1.0), jnp.inf)
    inside_fraction = jnp.where(d_max > 0, burley_cdf(jnp.minimum(r_clip, 1e30), d_max), 1.0)

    flat = _pack(prep.irradiance, prep.depth, prep.valid)
    rows_i = jnp.arange(h, dtype=dtype)[:, None]
    cols_i = jnp.arange(w, dtype=dtype)[None, :]
    z = prep.depth

    def body(i, acc):
        num, den = acc
        fi = jnp.asarray(i, dtype)
        v = 1 - (fi + 0.5) / samples * inside_fraction  # stratified CCDF, truncated to the image
        rho = burley_inverse_ccdf(v, jnp.ones_like(v))  # radius in units of d_max
        r_mm = rho * d_max
        off = r_mm * ppm
        theta = fi * GOLDEN_ANGLE
        # 1 / pdf of this sample (area density of the d_max profile at r), up to the per-pixel factor 8 pi d_max^2
        inv_pdf = rho / (jnp.exp(-rho) + jnp.exp(-rho / 3))
        ok_d = d_pix > 0
        inv_d = jnp.where(ok_d, 1.0 / jnp.where(ok_d, d_pix, 1.0), 0.0)
        # each pixel the fetch reads is its own point on the surface, with its own depth: weighting the corners
        # separately keeps light from leaking across a depth step through the interpolation
        for val, bw in _corners(flat, h, w, rows_i + off * jnp.sin(theta), cols_i + off * jnp.cos(theta),
                                interpolation=interpolation):
            v_q = val[..., 4] * bw
            dz_mm = jnp.where(v_q > 0, (val[..., 3] - z) * mm_per_unit, 0.0)
            r3 = _safe_sqrt(r_mm * r_mm + dz_mm * dz_mm)
            x = jnp.where(ok_d, r3[..., None] * inv_d, jnp.inf)
            wgt = (v_q * inv_pdf)[..., None] * _burley_weight_kernel(x)
            num = num + wgt * val[..., :3]
            den = den + wgt
        return num, den

    zeros = jnp.zeros_like(prep.irradiance)
    num, den = jax.lax.fori_loop(0, samples, body, (zeros, zeros))
    ok = den > 0
    scattered = jnp.where(ok, num / jnp.where(ok, den, 1.0), prep.irradiance)
    return _finish(buffers, prep, scattered)


def burley(
    buffers: Buffers,
    material: BurleyMaterial,
    camera: Camera,
    *,
    samples: int = 32,
    albedo_mode: str = "post",
    interpolation: str = "bilinear",
) -> Float[Array, "H W 3"]:
    """Screen-space Christensen–Burley normalised diffusion (one pass, ``samples`` spiral samples per pixel).

    Each sample's radius comes from stratified inverse-CDF sampling of the widest channel's profile (so one fetch
    serves R, G and B), its angle from the golden-angle spiral; it is placed in millimetres on the surface and
    projected with the pixel's depth. Its weight per channel is ``R_c(sqrt(r^2 + dz^2)) / pdf(r)`` (the depth
    difference dz makes light fall off across depth steps), and the weights are normalised per channel so flat
    lighting stays flat: energy is redistributed, not created. ``interpolation="bilinear"`` (default) makes the
    result continuous in d and depth (smooth for fitting); ``"nearest"`` fetches one pixel per sample.
    """
    _check_albedo_mode(albedo_mode)
    if interpolation not in ("bilinear", "nearest"):
        raise ValueError(f"interpolation={interpolation!r} is not one of ('bilinear', 'nearest')")
    if not isinstance(material, BurleyMaterial):
        raise TypeError(f"burley needs a BurleyMaterial, got {type(material).__name__}")
    if not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ValueError(f"samples must be a positive integer, got {samples!r}")
    return _burley_impl(buffers, material, camera, int(samples), albedo_mode, interpolation)


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


def _separable_pass(e: Array, z: Array, valid: Array, ppm: Array, offsets_px: Array, weights: Array,
                    reach_mm: Array, mm_per_unit: Array, follow_surface: bool, interpolation: str) -> Array:
    """One horizontal 1D pass (transpose for vertical). ``offsets_px (n, H, W)``, ``weights (n, H, W, 3)``."""
    h, w = z.shape
    flat = _pack(e, z, valid)
    rows_i = jnp.broadcast_to(jnp.arange(h, dtype=e.dtype)[:, None], (h, w))
    cols_i = jnp.arange(w, dtype=e.dtype)[None, :]

    def body(i, acc):
        fetched = _gather(flat, h, w, rows_i, cols_i + offsets_px[i], interpolation=interpolation)
        e_q, z_q, v_q = _unpack(fetched)
        # Jimenez's "follow the surface": blend the fetched colour towards the centre's as the depth difference grows
        # relative to how far this kernel carries light; invalid or off-image fetches count as the centre.
        keep = v_q
        if follow_surface:
            ok = reach_mm > 0
            ratio = jnp.abs(z_q - z) * mm_per_unit / jnp.where(ok, reach_mm, 1.0)
            keep = keep * (1 - jnp.clip(jnp.where(ok, ratio, 0.0), 0.0, 1.0))
        sample = keep[..., None] * e_q + (1 - keep)[..., None] * e
        return acc + weights[i] * sample

    return jax.lax.fori_loop(0, offsets_px.shape[0], body, jnp.zeros_like(e))


@eqx.filter_jit
def _separable_impl(buffers: Buffers, material, camera: Camera, taps: int, albedo_mode: str, follow_surface: bool,
                    interpolation: str) -> Array:
    dtype = _work_dtype(buffers.irradiance.dtype)
    offsets, weights = _kernel_table(material, taps, dtype)
    prep = _prepare(buffers, material.albedo, albedo_mode, dtype)
    ppm = px_per_mm(prep.depth, focal_px=camera.focal_px.astype(dtype), mm_per_unit=camera.mm_per_unit.astype(dtype))
    ppm = jnp.where(prep.valid, ppm, 0.0)
    offsets_px = jnp.moveaxis(offsets[prep.rows], -1, 0) * ppm[None]  # (n, H, W)
    w_pix = jnp.moveaxis(weights[prep.rows], -2, 0)  # (n, H, W, 3)
    reach_mm = jnp.max(jnp.abs(offsets), axis=-1)[prep.rows]  # (H, W)
    mm_per_unit = camera.mm_per_unit.astype(dtype)
    common = dict(follow_surface=follow_surface, interpolation=interpolation, mm_per_unit=mm_per_unit)
    e = _separable_pass(prep.irradiance, prep.depth, prep.valid, ppm, offsets_px, w_pix, reach_mm, **common)
    t = lambda a: jnp.swapaxes(a, 0, 1)
    tn = lambda a: jnp.swapaxes(a, 1, 2)
    e = t(_separable_pass(t(e), t(prep.depth), t(prep.valid), t(ppm), tn(offsets_px), tn(w_pix), t(reach_mm), **common))
    return _finish(buffers, prep, e)


def separable(
    buffers: Buffers,
    material: TwoGaussianMaterial | BurleyMaterial | ProfileMaterial,
    camera: Camera,
    *,
    taps: int = 25,
    albedo_mode: str = "post",
    follow_surface: bool = True,
    interpolation: str = "linear",
) -> Float[Array, "H W 3"]:
    """Separable subsurface scattering (Jimenez et al. 2015): a horizontal then a vertical 1D pass.

    The kernel is the artist-friendly two-Gaussian model (``TwoGaussianMaterial``) or the pre-integrated kernel of a
    profile (``BurleyMaterial``, ``ProfileMaterial``), ``taps`` taps per pass placed densest near the centre, offsets
    in mm projected per pixel by its depth. Weights sum to 1, so energy is redistributed, not created; with
    ``follow_surface`` a tap whose depth differs from the centre's by as much as the kernel's reach counts as the
    centre colour, so light does not cross depth discontinuities. ``interpolation``: "linear" (continuous in the
    offsets, for fitting) or "nearest".
    """
    _check_albedo_mode(albedo_mode)
    if interpolation not in ("linear", "nearest"):
        raise ValueError(f"interpolation={interpolation!r} is not one of ('linear', 'nearest')")
    if not isinstance(taps, (int, np.integer)) or taps < 1 or taps % 2 == 0:
        raise ValueError(f"taps must be an odd positive integer, got {taps!r}")
    mode = "bilinear" if interpolation == "linear" else "nearest"
    return _separable_impl(buffers, material, camera, int(taps), albedo_mode, bool(follow_surface), mode)


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


@eqx.filter_jit
def _translucency_impl(buffers: Buffers, params: STAParams, camera: Camera, light: DirectionalLight,
                       thickness: Array | None, material_albedo: Array) -> Array:
    dtype = _work_dtype(buffers.irradiance.dtype)
    prep = _prepare(buffers, material_albedo, "post", dtype)
    normal = buffers.normal.astype(dtype) if buffers.normal is not None else normals_from_depth(prep.depth, camera)
    pos = camera_positions(prep.depth, camera)
    view = -pos / jnp.linalg.norm(pos, axis=-1, keepdims=True)
    if buffers.thickness is not None:
        thick_units = buffers.thickness.astype(dtype)
    elif thickness is not None:
        thick_units = jnp.broadcast_to(jnp.asarray(thickness, dtype), prep.depth.shape)
    else:
        thick_units = jnp.zeros(prep.depth.shape, dtype)
    thick_mm = thick_units * camera.mm_per_unit.astype(dtype)
    added = sta_term(normal, view, light, params, thick_mm)
    out = prep.albedo_out * (prep.irradiance + added)
    out = jnp.where(prep.valid[..., None], out, buffers.irradiance.astype(dtype))
    return out.astype(buffers.irradiance.dtype)


def translucency(
    buffers: Buffers,
    params: STAParams,
    camera: Camera,
    light: DirectionalLight,
    *,
    albedo: Array | None = None,
    thickness: float | None = None,
) -> Float[Array, "H W 3"]:
    """The simple translucency approximation: ``albedo * (irradiance + STA light)`` on SSS pixels.

    ADDS light (not energy conserving): the back-light through the object's thickness is added on top of local
    diffuse shading. Thickness (scene units) comes from ``buffers.thickness``, else the constant ``thickness``, else
    0 (paper-thin). Normals come from ``buffers.normal`` (camera space) or are derived from depth. ``albedo (3,)`` is
    used where the buffers carry none (default white).
    """
    if not isinstance(params, STAParams):
        raise TypeError(f"translucency needs STAParams, got {type(params).__name__}")
    if not isinstance(light, DirectionalLight):
        raise TypeError(f"translucency needs a DirectionalLight, got {type(light).__name__}")
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
