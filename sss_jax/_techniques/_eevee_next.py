"""EEVEE Next's own screen-space subsurface pass (Blender 4.2 and later), as the engine executes it
(``eevee-next`` technique).

blender/blender ``source/blender/draw/engines/eevee_next/eevee_subsurface.cc`` (4.2-4.4; ``draw/engines/eevee/``
from 4.5, same code) ``SubsurfaceModule::precompute_samples_location``, ``burley_sample``, ``burley_eval``,
``burley_pdf``, and ``shaders/eevee_subsurface_convolve_comp.glsl`` (``main``). Once per TAA sample the engine draws
``(rand_u, rand_v)`` and lays out ``sample_len = 16`` samples in units of the pixel's largest radius:

- ``x_i = (1 + rand_v / 16) i / 16`` (sample 0 always at the centre), ``r_i = burley_sample(d0, x_i)`` with
  ``d0 = burley_setup(1, 1)`` and the CDF truncated at ``16 d`` (``SSS_BURLEY_TRUNCATE_CDF``), angle
  ``golden_angle i + 2 pi rand_u``, ``pdf_inv_i = TRUNCATE_CDF / burley_eval(d0, r_i)``;
- per pixel the pattern is turned by ``interleaved_gradient_noise(texel) * golden_angle`` and scaled to pixels by
  ``focal_px * max_radius / z``; nothing happens where that footprint is at most one pixel;
- each sample is a nearest fetch (the sampler clamps to a border of id 0: off-frame samples are rejected, as are
  samples on another object); its weight is ``burley_eval(d, |P_sample - P|)`` (the 3D distance of the view-space
  positions) times ``pdf_inv_i``, and the sum is normalised per channel.

``d = burley_setup(max(radius, 1e-4 max radius), A / max A)``; for sss_jax's material the radius is
``engines.EeveeNext``'s (``d 4 pi s(A / max A)``), so the pass's d is the material's wherever no channel is clamped.
``frames=K`` averages K TAA samples; sss_jax draws ``(rand_u, rand_v)`` for TAA sample ``k`` from the (2, 3) Halton
pair of ``k + 1 + seed`` (Blender takes them from its sampling module's low-discrepancy sequence: not read).
Texel rows count from the bottom of the frame and the pattern's y points up, as in OpenGL.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import check_host_count, checked, clamp
from .._materials import BurleyMaterial
from .._profiles import burley_inverse_ccdf
from .._scene import Buffers, Camera
from ._base import AbstractTechnique, built, frame_pieces, option
from ._common import (
    ALBEDO_MODES,
    _as_seed,
    _finish,
    _prepare,
    _safe_sqrt,
    _work_dtype,
    check_seed,
    weighted_mean,
)
from ._engine_frame import (
    computed_pixels,
    frame_geometry,
    nearest_fetch,
    pass_arguments,
    pixels_to_compute,
)

EEVEE_SAMPLE_LEN = 16  # SubsurfaceModule::end_sync, data_.sample_len (EEVEE Next, 4.2 and later)
EEVEE_BURLEY_TRUNCATE = 16.0  # SSS_BURLEY_TRUNCATE
EEVEE_BURLEY_TRUNCATE_CDF = 0.9963790093708328  # SSS_BURLEY_TRUNCATE_CDF: Burley's CDF at 16 d
EEVEE_MIN_RADIUS = 1e-4  # convolve shader: clamped_sss_radius (4.2; the uniform min_radius later)
GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))
FIRST_VERSION = (4, 2)  # EEVEE Next replaces EEVEE legacy (whose pass was separable) in Blender 4.2


def burley_setup(radius, albedo):
    """``burley_setup``: ``d = radius / (4 pi s)``, ``s = 1.9 - A + 3.5 (A - 0.8)^2`` (A already normalised)."""
    s = 1.9 - albedo + 3.5 * (albedo - 0.8) ** 2
    return 0.25 / math.pi * radius / s


EEVEE_D0 = burley_setup(1.0, 1.0)


def halton(index, base: int, dtype) -> Array:
    """The radical inverse of the non-negative integer ``index`` (traced int) in ``base``."""
    index = jnp.asarray(index, jnp.uint32)
    result = jnp.zeros((), dtype)
    f = 1.0
    for _ in range(20):  # 20 digits of base 2 cover 10^6 frames
        f = f / base
        result = result + f * (index % base).astype(dtype)
        index = index // base
    return result


def noise_terms(x: np.ndarray, y: np.ndarray, dtype) -> tuple[np.ndarray, np.ndarray]:
    """The two products of ``interleaved_gradient_noise``'s inner fraction, ``0.06711056 x`` for a row of texel columns
    ``x (1, W)`` and ``0.00583715 y`` for a column of texel rows ``y (H, 1)``, taken on the host in ``dtype`` (each
    rounded once) and passed to the pass as data (``interleaved_gradient_noise``)."""
    np_dtype = np.dtype(dtype)
    return (np.asarray(x, np_dtype) * np_dtype.type(0.06711056), np.asarray(y, np_dtype) * np_dtype.type(0.00583715))


def interleaved_gradient_noise(terms: tuple, dtype) -> Array:
    """Jimenez's interleaved gradient noise ``fract(52.9829189 fract(0.06711056 x + 0.00583715 y))`` of the texels
    ``(y, x)`` (Blender's ``interleaved_gradient_noise(texel, 0, 0)``), from ``noise_terms`` of a row of columns and a
    column of rows, in ``dtype``.

    The products are taken on the host (NumPy, each rounded once), and the device sums them and scales through an
    optimisation barrier: computed from iotas inside the pass, XLA folded or contracted the expression differently
    for a tile than for its frame, and the 1-ulp difference in ``inner`` (~13 at x = 200), times 53, turned the angle
    by ~1e-4 (a tile's pixels then fetched other texels than the whole frame's: 16 of 24,000 pixels of a 200x120 frame,
    by up to 2.5%). They reach the pass as arguments, so a tile's program is its shape's, whatever its origin."""
    a, b = terms
    frac = jnp.mod(jnp.asarray(a, dtype) + jnp.asarray(b, dtype), 1.0)
    return jnp.mod(jax.lax.optimization_barrier(52.9829189 * frac), 1.0)


def eevee_samples(frame, seed, dtype):
    """``(x, y, pdf_inv)`` of the 16 samples of TAA sample ``frame`` (units of the largest radius)."""
    key = jnp.asarray(frame, jnp.uint32) + 1 + jnp.asarray(seed, jnp.uint32)
    rand_u, rand_v = halton(key, 2, dtype), halton(key, 3, dtype)
    i = jnp.arange(EEVEE_SAMPLE_LEN, dtype=dtype)
    theta = GOLDEN_ANGLE * i + 2 * jnp.pi * rand_u
    x = (1 + rand_v / EEVEE_SAMPLE_LEN) * (i / EEVEE_SAMPLE_LEN)
    u = x * EEVEE_BURLEY_TRUNCATE_CDF
    r = jnp.where(u > 0, burley_inverse_ccdf(1 - u, jnp.asarray(EEVEE_D0, dtype)), 0.0)
    e3 = jnp.exp(-r / (3 * EEVEE_D0))
    eval_d0 = (e3 * e3 * e3 + e3) / (8 * jnp.pi * EEVEE_D0)  # burley_eval (C++), r < 16 d0 always
    return jnp.cos(theta) * r, jnp.sin(theta) * r, EEVEE_BURLEY_TRUNCATE_CDF / eval_d0


def _s_normalised(albedo: Array) -> Array:
    a = albedo / jnp.maximum(1e-6, jnp.max(albedo, axis=-1, keepdims=True))
    return 1.9 - a + 3.5 * (a - 0.8) ** 2


@eqx.filter_jit
def _eevee_next_impl(buffers: Buffers, material: BurleyMaterial, camera: Camera, frames: int, albedo_mode: str,
                     seed, noise: tuple, origin, frame_shape, start=None, size=None, idx=None) -> Array:
    dtype = _work_dtype(buffers.irradiance.dtype)
    d_table = checked(material.d_mm.astype(dtype), "d_mm")
    prep = _prepare(buffers, material.albedo, albedo_mode, dtype)
    h, w = buffers.depth.shape
    rows, cols, _, _, cx_f, cy_f = frame_geometry(buffers, camera, origin, frame_shape)
    focal = camera.focal_px.astype(dtype)
    mm_per_unit = camera.mm_per_unit.astype(dtype)
    ids = (buffers.material_id.astype(jnp.int32) if buffers.material_id is not None
           else jnp.ones((h, w), jnp.int32))
    ids = jnp.where(prep.valid, ids, 0)
    flat = jnp.concatenate([prep.irradiance, prep.depth[..., None], ids[..., None].astype(dtype)],
                           axis=-1).reshape(h * w, 5)
    # the pixels computed (``computed_pixels``): the buffer's, the window the caller keeps, or the compacted SSS
    # pixels; the fetches read the whole buffer
    take, put, _, _ = computed_pixels((h, w), start, size, idx)
    rows, cols, ids = take(rows), take(cols), take(ids)
    irradiance, z, valid = (take(a) for a in (prep.irradiance, prep.depth, prep.valid))
    mat_rows = take(prep.rows)
    albedo_mat = clamp(material.albedo.astype(dtype), 0.0, 1.0)[mat_rows]
    # the radius EEVEE Next is given for the material (engines.EeveeNext), in mm, and the d its shader derives
    s_norm = _s_normalised(albedo_mat)
    radius = jnp.where(valid[..., None], d_table[mat_rows] * 4 * jnp.pi * s_norm, 0.0)
    max_radius = jnp.max(radius, axis=-1)
    safe_max = jnp.where(max_radius > 0, max_radius, 1.0)
    clamped = jnp.maximum(EEVEE_MIN_RADIUS, radius / safe_max[..., None]) * safe_max[..., None]
    d = 0.25 / jnp.pi * clamped / s_norm  # burley_setup, mm
    scale_px = jnp.where(valid, focal * max_radius / (jnp.where(valid, z, 1.0) * mm_per_unit), 0.0)
    active = valid & (scale_px > 1.0)
    oy0, ox0 = (0, 0) if origin is None else (origin[0], origin[1])
    theta = interleaved_gradient_noise(noise, dtype) * GOLDEN_ANGLE  # the computed pixels' texels (noise_terms)
    cos_t, sin_t = jnp.cos(theta), jnp.sin(theta)
    # positions in frame pixels, so a tile computes each sample's position as the whole frame does; fetched at the
    # frame's pixel less the tile's origin
    frame_c = (cols[:1, :] if cols.ndim == 2 else cols).astype(dtype)  # a row of the window, or every pixel's
    frame_r = (rows[:, :1] if rows.ndim == 2 else rows).astype(dtype)
    # view-space x, y of the centre (scene units; y down as sss_jax's camera)
    px_c = (frame_c + 0.5 - cx_f) / focal * z
    py_c = (frame_r + 0.5 - cy_f) / focal * z
    inv_d = 1.0 / d

    def one_frame(k, acc):
        sx, sy, pdf_inv = eevee_samples(k, seed, dtype)

        def sample(i, carry):
            acc_e, acc_w = carry
            # from_rotation(theta) then from_scale: rotate the pattern, scale it to pixels; y up in the pattern
            ox = scale_px * (cos_t * sx[i] - sin_t * sy[i])
            oy = -scale_px * (sin_t * sx[i] + cos_t * sy[i])
            col_f, row_f = frame_c + ox, frame_r + oy
            fetched, inside = nearest_fetch(flat, h, w, jnp.floor(row_f + 0.5).astype(jnp.int32) - oy0,
                                            jnp.floor(col_f + 0.5).astype(jnp.int32) - ox0)
            ok = active & inside & (fetched[..., 4] == ids.astype(dtype))
            zs = fetched[..., 3]
            dx = (col_f + 0.5 - cx_f) / focal * zs - px_c
            dy = (row_f + 0.5 - cy_f) / focal * zs - py_c
            dz = zs - z
            r = _safe_sqrt(dx * dx + dy * dy + dz * dz) * mm_per_unit
            e3 = jnp.exp(-r[..., None] * inv_d / 3)
            weight = (e3 * e3 * e3 + e3) * 0.25 * inv_d * pdf_inv[i]  # burley_eval (GLSL) * pdf_inv
            weight = jnp.where(ok[..., None], weight, 0.0)
            return acc_e + weight * fetched[..., :3], acc_w + weight

        zero = jnp.zeros(irradiance.shape, dtype)
        acc_e, acc_w = jax.lax.fori_loop(0, EEVEE_SAMPLE_LEN, sample, (zero, zero))
        # safe_rcp; the quotient's derivative without the square of the weight total (as hdrp's, burley's)
        scattered = jnp.where(acc_w > 0, weighted_mean(acc_e, jnp.where(acc_w > 0, acc_w, 1.0)), 0.0)
        return acc + jnp.where(active[..., None], scattered, irradiance)

    total = jax.lax.fori_loop(0, frames, one_frame, jnp.zeros(irradiance.shape, dtype))
    return _finish(buffers, prep, put(prep.irradiance, total / frames))


class EeveeNextPass(AbstractTechnique):
    """EEVEE Next's screen-space subsurface pass (``eevee_subsurface_convolve_comp.glsl``) on sss_jax's buffers.

    ``frames`` TAA samples are averaged (each with its own ``rand_u``, ``rand_v``: EEVEE's viewport and renders
    accumulate 16 to 256 and more); ``blender_version`` must be 4.2 or later (the 16-sample pattern; EEVEE legacy,
    up to 4.1, ran a separable pass). Takes a ``BurleyMaterial``; ``EeveeNextPass.material_from_engine(params)``
    reads Principled BSDF inputs (``engines.EeveeNext.from_engine``). An eager call computes only the SSS pixels
    where they are under half the frame (``_engine_frame.compacted_pixels``: EEVEE's stencil; the same values as
    every pixel computed), a traced one every pixel.
    """

    name: ClassVar[str] = "eevee-next"
    conserves_energy: ClassVar[bool] = True
    sss_pixels_only: ClassVar[bool] = True
    material_type: ClassVar[type | tuple[type, ...]] = BurleyMaterial

    frames: int = option(16, "TAA samples accumulated (each a new 16-sample pattern)")
    blender_version: str = option("4.2", "Blender version (4.2 or later: the 16-sample pattern)")
    albedo_mode: str = option("post", "albedo applied after the scatter, or split before and after",
                              choices=ALBEDO_MODES)
    seed: int = option(0, "offset into the TAA sample sequence", static=False)

    def __check_init__(self):
        check_host_count(self.frames, "eevee-next: frames")
        check_seed("eevee-next", self.seed)
        from ..engines._blender import parse_version

        try:
            version = parse_version(self.blender_version)
        except (TypeError, ValueError) as e:
            raise type(e)(f"eevee-next: {e}") from None
        if version < FIRST_VERSION:
            raise ValueError(f"eevee-next: blender_version {self.blender_version}: EEVEE Next starts with 4.2; earlier "
                             "versions have EEVEE legacy, whose pass is separable (not this one)")

    def __call__(self, buffers: Buffers, material: BurleyMaterial, camera: Camera, *,
                 origin: tuple[int, int] = (0, 0), frame_shape: tuple[int, int] | None = None,
                 keep: tuple[int, int, int, int] | None = None) -> Float[Array, "H W 3"]:
        """``origin``, ``frame_shape``: the buffer's place in the whole frame (a tile's); ``keep=(row0, col0, rows,
        cols)``: the only pixels of the buffer the caller keeps (a tile's, without its halo): only they are computed
        (the samples still read the whole buffer), the others come back as their local shading."""
        self.check_material(material)
        placed = pass_arguments(self.name, self.albedo_mode, buffers, origin, frame_shape, material.count)
        # only the SSS pixels (EEVEE's stencil) where the call can count them, else the kept window or every pixel
        start, size, idx = pixels_to_compute(self.name, buffers, material, camera, keep)
        h, w = buffers.depth.shape
        oy, ox = (int(v) for v in origin)  # checked by pass_arguments
        fh = h if placed[1] is None else placed[1][0]
        dtype = _work_dtype(buffers.irradiance.dtype)
        # the computed pixels' texels; rows count from the frame's bottom (OpenGL)
        if idx is not None:
            safe = np.minimum(idx, h * w - 1)
            noise = noise_terms(ox + safe % w, fh - 1 - (oy + safe // w), dtype)
        else:
            r0, c0, kh, kw = (0, 0, h, w) if start is None else (*(int(v) for v in keep[:2]), *size)
            noise = noise_terms(np.arange(ox + c0, ox + c0 + kw)[None, :],
                                (fh - 1 - np.arange(oy + r0, oy + r0 + kh))[:, None], dtype)
        return _eevee_next_impl(buffers, material, camera, int(self.frames), self.albedo_mode,
                                _as_seed(self.seed), noise, *placed, start, size,
                                None if idx is None else jnp.asarray(idx))

    def pieces(self, count: int) -> tuple[tuple["EeveeNextPass", float], ...] | None:
        """The ``frames`` in about ``count`` calls of consecutive TAA samples (sample k of seed s is ``k + 1 + s``
        of the sequence: a group from sample a takes seed ``s + a``), weighted by their share."""
        return frame_pieces(self, count, lambda seed, first: (seed + first) & 0xFFFFFFFF)

    def reach_px(self, buffers: Buffers, material: BurleyMaterial, camera: Camera) -> int:
        """The farthest sample (``x < 1 + 1/16`` of the truncated CDF, at most 16 d0 max radius) at the nearest
        SSS pixel."""
        from ._hdrp import _max_ppm

        a = np.asarray(material.albedo, np.float64)
        s = 1.9 - a / np.maximum(1e-6, a.max(-1, keepdims=True))
        s = s + 3.5 * (a / np.maximum(1e-6, a.max(-1, keepdims=True)) - 0.8) ** 2
        radius = float(np.max(np.asarray(material.d_mm, np.float64) * 4 * math.pi * s))
        return int(math.ceil(_max_ppm(buffers, camera) * EEVEE_BURLEY_TRUNCATE * EEVEE_D0 * radius)) + 1

    @staticmethod
    def material_from_engine(params: dict[str, Any]) -> BurleyMaterial:
        """The ``BurleyMaterial`` for Principled BSDF inputs (``engines.EeveeNext.from_engine``)."""
        from ..engines import get_engine

        albedo, d = get_engine("eevee-next").from_engine(dict(params))
        return BurleyMaterial(albedo, d)


def eevee_next(buffers: Buffers, material: BurleyMaterial, camera: Camera, **options) -> Float[Array, "H W 3"]:
    """EEVEE Next's own subsurface pass: ``EeveeNextPass(**options)(buffers, material, camera)``."""
    return built(EeveeNextPass, options)(buffers, material, camera)
