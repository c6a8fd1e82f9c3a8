"""Reference: dense convolution with the exact profile integrated over each pixel's footprint (slow by design)."""

from __future__ import annotations

import math
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._materials import BurleyMaterial, ProfileMaterial
from .._scene import Buffers, Camera
from .._units import px_per_mm
from ._common import (
    _check_albedo_mode,
    _check_border,
    _finish,
    _is_concrete,
    _prepare,
    _safe_sqrt,
    _sss_mask,
    _work_dtype,
    check_one_image,
    frame_energy_fraction,
    weighted_mean,
)
from ._dispatch import check_tile, crop, kept_window, uncrop

_THETA_NODES, _THETA_WEIGHTS = np.polynomial.legendre.leggauss(16)




def reference_radius_px(buffers: Buffers, material, camera: Camera, *, energy: float = 0.999, cap: int = 96) -> int:
    """Window radius (px, host side) holding ``energy`` of the widest profile at the nearest SSS pixel, no wider than
    the frame (an offset past it never lands inside: the energy out there is accounted for analytically), capped at
    ``cap``. ``reference_energy_held`` says how much of the profile a capped window represents."""
    valid = np.asarray(_sss_mask(buffers))
    if not valid.any():
        return 1
    depth = np.asarray(buffers.depth, dtype=np.float64)[valid]
    ppm_max = float(camera.focal_px) / (float(np.min(depth)) * float(camera.mm_per_unit))
    radius_mm = material.radius_mm(energy)
    extent = max(buffers.depth.shape[-2:]) - 1
    return int(max(1, min(cap, extent, math.ceil(radius_mm * ppm_max))))


def reference_energy_held(buffers: Buffers, material, camera: Camera, radius_px: int, *,
                          frame_shape: tuple[int, int] | None = None) -> float:
    """Host side: the smallest fraction of the widest profile's energy that ``reference`` with window ``radius_px``
    accounts for at any SSS pixel: 1 where the window spans the frame (every offset that lands inside is in the
    window, the rest leaves the frame and is accounted for analytically), else the energy within the disc the window
    holds at the nearest SSS pixel (the light farther away, inside the frame, is missing from the result: the pixel
    is normalised by what the window saw, as if that light had come from inside it). ``frame_shape``: the whole
    frame's ``(H, W)`` where ``buffers`` is a tile of it (``None``: the buffers are the frame)."""
    valid = np.asarray(_sss_mask(buffers))
    frame_shape = tuple(buffers.depth.shape[-2:]) if frame_shape is None else tuple(frame_shape)
    if not valid.any() or radius_px >= max(frame_shape) - 1:
        return 1.0
    depth = np.asarray(buffers.depth, dtype=np.float64)[valid]
    ppm_max = float(camera.focal_px) / (float(np.min(depth)) * float(camera.mm_per_unit))
    reach_mm = (radius_px + 0.5) / ppm_max
    lo, hi = 0.0, 1.0  # bisection on the energy whose radius is the window's (radius_mm is monotone in it)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if material.radius_mm(mid) <= reach_mm else (lo, mid)
    return lo


from .._errors import ReferenceWindowWarning as ReferenceWindowWarning  # noqa: E402  (defined in _errors)


@eqx.filter_jit
def _reference_impl(buffers: Buffers, material, camera: Camera, radius_px: int, albedo_mode: str,
                    near_subsamples: int, border: str = "leaves", origin: Array | tuple[int, int] = (0, 0),
                    frame_shape: tuple[int, int] | None = None, start: Array | None = None,
                    size: tuple[int, int] | None = None) -> Array:
    dtype = _work_dtype(buffers.irradiance.dtype)
    prep = _prepare(buffers, material.albedo, albedo_mode, dtype)
    h, w = buffers.depth.shape
    # the pixels computed: the buffer's, or the window the caller keeps (``keep``: ``start``, ``size``); the window
    # around each reads the whole buffer
    valid, depth, e = (crop(a, start, size) for a in (prep.valid, prep.depth, prep.irradiance))
    kh, kw = depth.shape
    r0, c0 = (0, 0) if start is None else (start[0], start[1])
    mm_per_unit = camera.mm_per_unit.astype(dtype)
    ppm = px_per_mm(depth, focal_px=camera.focal_px.astype(dtype), mm_per_unit=mm_per_unit)
    ppm = jnp.where(valid, ppm, 0.0)
    pixel_mm = jnp.where(ppm > 0, 1.0 / jnp.where(ppm > 0, ppm, 1.0), 0.0)  # side of a pixel on the surface, mm
    radial, cdf = material.pixel_profile(crop(prep.rows, start, size), valid, dtype)

    # centre pixel: exact mass of the profile over the square of half-side a, with the 1/r peak integrated
    # analytically through the CDF: (4/pi) int_0^{pi/4} CDF(a / cos t) dt
    a = 0.5 * pixel_mm
    nodes = jnp.asarray(_THETA_NODES, dtype)
    t = (nodes + 1) * (math.pi / 8)
    tw = jnp.asarray(_THETA_WEIGHTS, dtype) * (math.pi / 8)
    centre_mass = sum(tw[k] * cdf(a / jnp.cos(t[k])) for k in range(t.shape[0])) * (4 / math.pi)
    centre_w = jnp.where(valid[..., None], centre_mass, 0.0)
    num, den = centre_w * e, centre_w
    if border == "leaves":  # the profile's energy beyond the frame leaves: it counts as dark surface (_common)
        # frame coordinates: a tile's border is the frame's, not its own (pixels of the frame beyond the tile are
        # read from its halo like any other)
        frame_h, frame_w = (h, w) if frame_shape is None else frame_shape
        rows, cols = jnp.meshgrid(jnp.arange(kh) + origin[0] + r0, jnp.arange(kw) + origin[1] + c0, indexing="ij")
        leaves = 1 - frame_energy_fraction(cdf, rows, cols, frame_h, frame_w, pixel_mm)
        den = den + jnp.where(valid[..., None], jnp.maximum(leaves, 0.0), 0.0)

    k = radius_px
    pad = lambda x: jnp.pad(x, [(k, k), (k, k)] + [(0, 0)] * (x.ndim - 2))
    e_pad = pad(prep.irradiance * prep.valid[..., None])
    z_pad = pad(jnp.where(prep.valid, prep.depth, 0.0))
    v_pad = pad(prep.valid.astype(dtype))

    def neighbour_weight(dy, dx, sub: int):
        """Mass of the profile over neighbour pixel (dy, dx): sub x sub midpoint rule on the surface, 3D distance."""
        y, x = (k + dy, k + dx) if start is None else (k + dy + r0, k + dx + c0)
        z_q = jax.lax.dynamic_slice(z_pad, (y, x), (kh, kw))
        v_q = jax.lax.dynamic_slice(v_pad, (y, x), (kh, kw))
        e_q = jax.lax.dynamic_slice(e_pad, (y, x, 0 if start is None else jnp.zeros_like(y)), (kh, kw, 3))
        dz_mm = jnp.where(v_q > 0, (z_q - depth) * mm_per_unit, 0.0)
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
            # a skipped offset is evaluated at a kept one, (outer, outer), and dropped: evaluated where it is, the
            # centre's one-point rule is R(0) = inf, whose gradient through the mask is 0 inf = NaN (every depth
            # and focal gradient, for radius_px > 6)
            wgt, e_q = neighbour_weight(jnp.where(skip, outer, dy), jnp.where(skip, outer, dx), sub)
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
    scattered = jnp.where(ok, weighted_mean(num, jnp.where(ok, den, 1.0)), e)
    return _finish(buffers, prep, uncrop(prep.irradiance, scattered, start))


def check_reference_counts(radius_px, near_subsamples) -> None:
    """``reference``'s window (a non-negative integer; None: the default, read from the frame) and its near
    subsamples (a positive integer): what the function checks and a ``Reference`` object when it is made."""
    for name, value, least, what in (("radius_px", radius_px, 0, "non-negative"),
                                     ("near_subsamples", near_subsamples, 1, "positive")):
        if value is None and name == "radius_px":
            continue
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < least:
            raise ValueError(f"reference: {name} must be a {what} integer, got {value!r}")


def reference(
    buffers: Buffers,
    material: BurleyMaterial | ProfileMaterial,
    camera: Camera,
    *,
    radius_px: int | None = None,
    albedo_mode: str = "post",
    near_subsamples: int = 6,
    border: str = "renormalise",
    origin: tuple[int, int] = (0, 0),
    frame_shape: tuple[int, int] | None = None,
    keep: tuple[int, int, int, int] | None = None,
) -> Float[Array, "H W 3"]:
    """Ground truth: every pixel within ``radius_px`` contributes the exact mass of the profile over its footprint.

    The centre pixel's mass is integrated through the profile's CDF (so r -> 0 is finite); neighbours use a midpoint
    rule (``near_subsamples``^2 points within two pixels, 2x2 within six, one beyond) at the 3D distance (depth
    difference included); weights are normalised by the profile's energy over the valid pixels in the window (light
    reaching pixels without a surface inside the frame is taken from the pixels with one) -- with
    ``border="leaves"`` plus its energy beyond the frame, which leaves (it counts as dark surface). ``radius_px``
    defaults to the radius holding 99.9% of the widest channel's energy at the nearest SSS pixel, at most the
    frame's extent (host side; pass it explicitly under ``jit``) and at most 96 px; where the window holds less than
    99.9% of the energy (``reference_energy_held``), a ``ReferenceWindowWarning`` says how much. Slow by design: the
    cost grows with the window's area.
    ``border="renormalise"`` (the default, as ``burley`` and ``separable``): no energy leaves at the frame (the
    window's weights renormalised); ``"leaves"`` for a surface that really ends at the frame.

    Tiles: ``origin=(row0, col0)`` is this buffer's top-left pixel in the whole frame and ``frame_shape=(H, W)`` the
    frame's size (``None``: the buffer is the frame). The frame border follows the frame, so a tile cut with a halo
    of ``radius_px`` pixels on every side (fewer where the frame ends) gives the untiled frame's pixels inside the
    halo. A tile needs the frame's window (``radius_px``: ``Reference().reach_px`` of the whole frame): the default
    would be the tile's own, other pixels, so a placed tile without ``radius_px`` is an error.
    ``keep=(row0, col0, rows, cols)``: the only pixels of the buffer the caller keeps (a tile's, without its halo):
    only they are computed (their windows read the whole buffer), the others come back as their local shading.
    """
    _check_border(border)
    _check_albedo_mode(albedo_mode)
    check_one_image("reference", buffers, getattr(material, "count", None), camera=camera)
    if not isinstance(material, (BurleyMaterial, ProfileMaterial)):
        raise TypeError(f"reference needs a BurleyMaterial or ProfileMaterial, got {type(material).__name__}")
    h, w = buffers.depth.shape[-2:]
    origin, frame_shape = check_tile((h, w), origin, frame_shape)
    window = kept_window("reference", keep, (h, w))
    placed = origin != (0, 0) or frame_shape != (h, w)
    if radius_px is None and placed:
        raise ValueError("reference: a tile of a larger frame needs the frame's window, radius_px (e.g. "
                         "Reference().reach_px(<the whole frame's buffers>, material, camera)); the default would "
                         "be this tile's own window: other pixels")
    if radius_px is None:
        if not _is_concrete(buffers, material, camera):  # the window's size is a shape: it cannot follow traced data
            raise ValueError("reference under jit/vmap/grad needs radius_px (the window's size is read from the "
                             "buffers and the material, traced here): e.g. Reference().reach_px(buffers, material, "
                             "camera) outside the transformation")
        radius_px = reference_radius_px(buffers, material, camera)
    check_reference_counts(radius_px, near_subsamples)
    # a window past the frame reaches no further pixel (every pixel of the frame lies within max(H, W) - 1 along
    # each axis): the same result, without a window of (2 radius_px + 1)^2 offsets
    radius_px = min(int(radius_px), max(frame_shape) - 1)
    if _is_concrete(buffers, material, camera):
        held = reference_energy_held(buffers, material, camera, int(radius_px), frame_shape=frame_shape)
        if held < 0.999:
            warnings.warn(f"reference: the {radius_px}-px window holds {held:.1%} of the profile's energy at the "
                          f"nearest SSS pixel (the frame needs {max(frame_shape) - 1} px to hold all of "
                          f"it): the result misses the rest; pass a larger radius_px", ReferenceWindowWarning,
                          stacklevel=2)
    # a tile's origin is traced (the tiles of one shape share one program); the whole frame's program is unchanged
    tile = {} if not placed else {"origin": jnp.asarray(origin, jnp.int32), "frame_shape": frame_shape}
    return _reference_impl(buffers, material, camera, int(radius_px), albedo_mode, int(near_subsamples), border,
                           **tile, start=window[0], size=window[1])

