"""``burley`` as a GPU runs it: every pixel of the frame in one fused loop over the samples, masked, no host sync.

The CPU formulation counts the active pixels on the host and compacts them; on a GPU that round trip costs more than
the pixels it saves. Here every pixel runs the sample loop and the inactive ones are masked at the end (the Pallas
kernel skips the loop for a block of pixels with none active: the cost follows the scene on the device). The sample
pattern is an input: ``sample_u (S,)`` (stratified positions in the profile's CDF, truncated per pixel to the image
diagonal) and ``sample_theta (S,)`` (angles), plus a per-pixel rotation ``phi (H, W)`` added to every angle (0:
the golden-angle spiral shared by all pixels), so another sampling pattern (a per-pixel hash rotation, a pattern per
frame) is a change of inputs, not of the kernel.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import checked
from .._kernels import spiral_samples
from .._materials import BurleyMaterial
from .._profiles import burley_cdf, burley_inverse_ccdf
from .._scene import Buffers, Camera
from .._units import px_per_mm
from ._burley_spec import _BURLEY_R99, _burley_weight_kernel
from ._common import _safe_sqrt


def sample_pattern(samples: int, dtype) -> tuple[Array, Array]:
    """The golden-angle spiral (``spiral_samples``): stratified CDF positions ``(i + 1/2) / S`` and angles
    ``i * GOLDEN_ANGLE``."""
    spiral = spiral_samples(samples, dtype=dtype)
    return spiral.cdf, spiral.angles


def sample_term(u: Array, theta: Array, pix: dict, fetch, *, height: int, width: int, mm_per_unit: Array,
                interpolation: str, inverse_ccdf, weight_channels: int) -> tuple[list[Array], list[Array]]:
    """What one sample adds to each pixel's numerator (3 channels) and denominator (``weight_channels``).

    ``pix``: per-pixel planes (``row``, ``col`` as floats, ``e`` (3 planes), ``z``, ``dmax``, ``ppm``,
    ``inside`` (the profile's fraction within the image diagonal), ``phi``, ``inv_d``/``ok_d`` (per weight channel)).
    ``fetch(idx)``: the channels and depth at flat pixel index ``idx`` (row-major, clipped into the frame).
    Layout-free (a frame or a block of pixels): the XLA loop and the Pallas kernel share it."""
    rho = inverse_ccdf(1 - u * pix["inside"])  # radius in units of d_max
    r_mm = rho * pix["dmax"]
    off = r_mm * pix["ppm"]
    angle = theta + pix["phi"]
    y, x = pix["row"] + off * jnp.sin(angle), pix["col"] + off * jnp.cos(angle)
    # 1 / pdf of this sample (area density of the d_max profile at r), up to the per-pixel factor 8 pi d_max^2
    inv_pdf = rho / (jnp.exp(-rho) + jnp.exp(-rho / 3))
    # clip first: huge or NaN offsets must not overflow the integer cast
    x = jnp.clip(jnp.where(jnp.isnan(x), -4.0, x), -4.0, width + 3.0)
    y = jnp.clip(jnp.where(jnp.isnan(y), -4.0, y), -4.0, height + 3.0)
    if interpolation == "nearest":
        corners = [(jnp.round(y), jnp.round(x), None)]
    else:
        x0, y0 = jnp.floor(x), jnp.floor(y)
        fx, fy = x - x0, y - y0
        corners = [(y0, x0, (1 - fy) * (1 - fx)), (y0, x0 + 1, (1 - fy) * fx), (y0 + 1, x0, fy * (1 - fx)),
                   (y0 + 1, x0 + 1, fy * fx)]
    num, den = [0.0] * 3, [0.0] * weight_channels
    for yi, xi, corner_weight in corners:
        inside = (xi >= 0) & (xi <= width - 1) & (yi >= 0) & (yi <= height - 1)
        idx = jnp.clip(yi, 0, height - 1).astype(jnp.int32) * width + jnp.clip(xi, 0, width - 1).astype(jnp.int32)
        *eq, zq = fetch(idx)
        # each pixel the fetch reads is its own point on the surface, with its own depth (no interpolated depth
        # across a step); validity travels in the depth (0 where a pixel takes no part)
        ok = inside & (zq > 0)
        v_q = jnp.where(ok, 1.0 if corner_weight is None else corner_weight, 0.0)
        dz_mm = jnp.where(ok, (zq - pix["z"]) * mm_per_unit, 0.0)
        r3 = _safe_sqrt(r_mm * r_mm + dz_mm * dz_mm)
        base = v_q * inv_pdf
        wgt = [base * _burley_weight_kernel(jnp.where(pix["ok_d"][c], r3 * pix["inv_d"][c], jnp.inf))
               for c in range(weight_channels)]
        num = [num[c] + wgt[min(c, weight_channels - 1)] * eq[c] for c in range(3)]
        den = [den[c] + wgt[c] for c in range(weight_channels)]
    return num, den


def normalise(num: list[Array], den: list[Array], e: list[Array]) -> list[Array]:
    """Each channel's weighted mean; a pixel no sample reached keeps its own value."""
    out = []
    for c in range(3):
        d = den[min(c, len(den) - 1)]
        ok = d > 0
        out.append(jnp.where(ok, num[c] / jnp.where(ok, d, 1.0), e[c]))
    return out


def gather_burley(pix: dict, sample_u: Array, sample_theta: Array, *, height: int, width: int,
                  mm_per_unit: Array, interpolation: str, weight_channels: int) -> list[Array]:
    """The sample loop over flat per-pixel planes (N = H W), XLA formulation: the scattered channels (3 planes)."""
    packed = jnp.stack([*pix["e"], pix["z"]], axis=-1)  # (N, 4): one gather per corner fetches all four
    fetch = lambda idx: list(jnp.moveaxis(jnp.take(packed, idx, axis=0), -1, 0))
    inverse_ccdf = lambda v: burley_inverse_ccdf(v, jnp.ones_like(v))

    def body(i, acc):
        num, den = sample_term(sample_u[i], sample_theta[i], pix, fetch, height=height, width=width,
                               mm_per_unit=mm_per_unit, interpolation=interpolation, inverse_ccdf=inverse_ccdf,
                               weight_channels=weight_channels)
        return tuple(a + b for a, b in zip(acc[0], num)), tuple(a + b for a, b in zip(acc[1], den))

    zeros = jnp.zeros_like(pix["z"])
    num, den = jax.lax.fori_loop(0, sample_u.shape[0], body, ((zeros,) * 3, (zeros,) * weight_channels))
    return normalise(list(num), list(den), pix["e"])


def pixel_planes(buffers: Buffers, material: BurleyMaterial, camera: Camera, prep, min_footprint_px: float,
                 weight_channels: int, dtype) -> tuple[dict, Array]:
    """The flat per-pixel planes ``sample_term`` reads, and the active mask (H, W), as ``burley`` defines them."""
    d_table = checked(material.d_mm.astype(dtype), "d_mm")
    h, w = buffers.depth.shape
    mm_per_unit = camera.mm_per_unit.astype(dtype)
    d_pix = jnp.where(prep.valid[..., None], d_table[prep.rows], 0.0)  # (H, W, 3)
    d_max = jnp.max(d_pix, axis=-1)
    ppm = px_per_mm(prep.depth, focal_px=camera.focal_px.astype(dtype), mm_per_unit=mm_per_unit)
    ppm = jnp.where(prep.valid, ppm, 0.0)
    active = prep.valid & (d_max * ppm * _BURLEY_R99 >= min_footprint_px)
    # samples beyond the image diagonal can never land: the profile is sampled truncated there
    r_clip = jnp.where(ppm > 0, math.hypot(h, w) / jnp.where(ppm > 0, ppm, 1.0), jnp.inf)
    inside = jnp.where(d_max > 0, burley_cdf(jnp.minimum(r_clip, 1e30), d_max), 1.0)
    d_w = d_pix[..., :weight_channels]
    ok_d = d_w > 0
    inv_d = jnp.where(ok_d, 1.0 / jnp.where(ok_d, d_w, 1.0), 0.0)
    flat = lambda a: a.reshape(h * w)
    idx = jnp.arange(h * w, dtype=jnp.int32)
    pix = {"row": (idx // w).astype(dtype), "col": (idx % w).astype(dtype),
           "e": [flat(prep.irradiance[..., c]) for c in range(3)], "z": flat(prep.depth), "dmax": flat(d_max),
           "ppm": flat(ppm), "inside": flat(inside), "phi": jnp.zeros(h * w, dtype),
           "inv_d": [flat(inv_d[..., c]) for c in range(weight_channels)],
           "ok_d": [flat(ok_d[..., c]) for c in range(weight_channels)]}
    return pix, active
