"""Unity HDRP's own screen-space subsurface pass, as the engine executes it (``hdrp`` technique).

Unity-Technologies/Graphics ``com.unity.render-pipelines.high-definition/Runtime/Material/SubsurfaceScattering/
SubsurfaceScattering.compute`` (``EvaluateSss``, ``EvaluateSample``, ``ComputeBilateralWeight``), with
``Runtime/Material/DiffusionProfile/DiffusionProfile.hlsl`` (``SampleBurleyDiffusionProfile``,
``EvalBurleyDiffusionProfile``) and ``DiffusionProfileSettings.cs`` (``SSS_PIXELS_PER_SAMPLE = 4``,
``DefaultSssSampleBudgetForQualityLevel`` Low/Medium/High = 20/40/80, Max 1000; ``UpdateKernel``: the filter radius
is the radius holding 0.997 of the widest channel's energy). Per SSS pixel:

- ``n = min(floor(pi (filter radius px)^2 / 4), budget)``; ``n < 1`` keeps the pixel's own irradiance;
- sample ``i < n`` at the widest channel's Burley radius for ``u = i/n + 0.5/n`` (the whole CDF), angle
  ``2 pi frac(i / golden ratio) + phase``, ``phase`` a per-pixel hash (sss_jax's ``spiral_rotation`` of the frame
  pixel, frame and seed: HDRP hashes the pixel and its depth bits; TAA sees a new pattern per frame);
- a point fetch at ``pixel + round(px_per_mm r (cos, sin))``;
- weight ``EvalBurleyDiffusionProfile(sqrt(r^2 + (dz mm)^2), S) * rcpPdf``: each channel's profile at the 3D
  distance (the bilateral weight) over the sampling pdf of the widest channel;
- samples off the frame or on a pixel without SSS (HDRP tags SSS lighting non-zero and skips zero lighting) are
  skipped, and the weights renormalised over the rest: ``albedo * sum(w E) / sum(w)``.

``d_mm`` is HDRP's scattering distance (``1 / shapeParam``, the exact conversion of ``engines.Hdrp``); a channel
with ``d = 0`` keeps its own irradiance (HDRP would divide by ``FLT_MIN``). Otherwise what HDRP renders is kept where
it is not flat light: a pixel whose samples all land off the frame or on pixels without SSS (a 1x1 frame, a sliver
of skin at the frame's edge), and a channel whose weights all underflow in float32 (a d thousands of times below
the widest channel's), come out black, as ``albedo * totalIrradiance / max(totalWeight, FLT_MIN)`` does in the
engine (sss_jax's ``burley`` keeps the pixel's own light there). ``frames=K`` averages K frames, each
with its own rotation hash (what TAA converges to).
"""

from __future__ import annotations

import math
import warnings
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import check_host_count, checked
from .._materials import BurleyMaterial
from .._profiles import burley_inverse_ccdf
from .._scene import Buffers, Camera
from .._units import px_per_mm
from ._base import AbstractTechnique, built, frame_pieces, option
from ._burley import spiral_rotation
from ._burley_spec import unit_radius
from ._common import (
    ALBEDO_MODES,
    SamplingWarning,
    _as_seed,
    _finish,
    _is_concrete,
    _prepare,
    _safe_sqrt,
    _sss_mask,
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

HDRP_QUALITY_BUDGETS = {"low": 20, "medium": 40, "high": 80}  # DefaultSssSampleBudgetForQualityLevel
HDRP_MAX_BUDGET = 1000  # DefaultSssSampleBudgetForQualityLevel.Max
HDRP_PIXELS_PER_SAMPLE = 4  # DiffusionProfileConstants.SSS_PIXELS_PER_SAMPLE
HDRP_FILTER_CDF = 0.997  # DiffusionProfileSettings.UpdateKernel: the filter radius holds 99.7% of the energy
GOLDEN_RATIO = (1.0 + math.sqrt(5.0)) / 2.0
# the filter radius in units of d: Burley's CDF 1 - e^-x/4 - 3 e^(-x/3)/4 = 0.997 (closed form of _profiles)
FILTER_RADIUS_UNITS = unit_radius(1 - HDRP_FILTER_CDF)


def hdrp_budget(quality: str, budget: int | None) -> int:
    """The sample budget: ``budget`` where given (1..1000, HDRP's custom budget), else the quality level's."""
    if budget is not None:
        return check_host_count(budget, "hdrp: budget", hi=HDRP_MAX_BUDGET)
    if quality not in HDRP_QUALITY_BUDGETS:
        raise ValueError(f"hdrp: quality={quality!r} is not one of {tuple(HDRP_QUALITY_BUDGETS)}")
    return HDRP_QUALITY_BUDGETS[quality]


def _exp_sum(x: Array) -> Array:
    """``exp(-x/3) + exp(-x)`` (the Burley profile times ``8 pi r / S``), one exponential."""
    e3 = jnp.exp(-x / 3)
    return e3 * (1 + e3 * e3)


@eqx.filter_jit
def _hdrp_impl(buffers: Buffers, material: BurleyMaterial, camera: Camera, budget: int, frames: int,
               albedo_mode: str, seed, origin, frame_shape, start=None, size=None, idx=None) -> Array:
    dtype = _work_dtype(buffers.irradiance.dtype)
    d_table = checked(material.d_mm.astype(dtype), "d_mm")
    prep = _prepare(buffers, material.albedo, albedo_mode, dtype)
    h, w = buffers.depth.shape
    rows, cols, _, _, _, _ = frame_geometry(buffers, camera, origin, frame_shape)
    mm_per_unit = camera.mm_per_unit.astype(dtype)
    flat = jnp.concatenate([prep.irradiance, prep.depth[..., None], prep.valid[..., None].astype(dtype)],
                           axis=-1).reshape(h * w, 5)
    # the pixels computed (``computed_pixels``): the buffer's, the window the caller keeps, or the compacted SSS
    # pixels; the fetches read the whole buffer
    take, put, local_r, local_c = computed_pixels((h, w), start, size, idx)
    rows, cols = take(rows), take(cols)
    irradiance, depth, valid = (take(a) for a in (prep.irradiance, prep.depth, prep.valid))
    d_pix = jnp.where(valid[..., None], d_table[take(prep.rows)], 0.0)  # (pixels..., 3), mm
    d_max = jnp.max(d_pix, axis=-1)
    ppm = jnp.where(valid, px_per_mm(depth, focal_px=camera.focal_px.astype(dtype), mm_per_unit=mm_per_unit), 0.0)
    filter_px = FILTER_RADIUS_UNITS * d_max * ppm
    count = jnp.floor(jnp.pi * filter_px * filter_px / HDRP_PIXELS_PER_SAMPLE)
    n = jnp.minimum(count, budget)  # float: exact for counts far below 2^24
    active = valid & (n >= 1)
    n_safe = jnp.where(active, n, 1.0)
    has_d = d_pix > 0
    shape = jnp.where(has_d, 1.0 / jnp.where(has_d, d_pix, 1.0), 0.0)  # S = 1/d per channel (mm^-1)

    def one_frame(k, acc):
        phase = spiral_rotation(rows, cols, k, seed, dtype=dtype)

        def sample(i, carry):
            total_e, total_w = carry
            fi = jnp.asarray(i, dtype)
            # samples past the pixel's count (i >= n, masked below) take the last one's u: u > 1 would put a NaN
            # radius into the masked branch, and NaN into every gradient
            fc = jnp.minimum(fi, n_safe - 1)
            u = fc / n_safe + 0.5 / n_safe
            r = burley_inverse_ccdf(1 - u, jnp.where(active, d_max, 1.0))  # mm, the widest channel's
            phi = 2 * jnp.pi * jnp.mod(fi / GOLDEN_RATIO, 1.0)
            psi = phase + phi
            step = ppm * r
            sr = local_r + jnp.round(step * jnp.sin(psi)).astype(jnp.int32)
            sc = local_c + jnp.round(step * jnp.cos(psi)).astype(jnp.int32)
            fetched, inside = nearest_fetch(flat, h, w, sr, sc)
            ok = active & (fi < n) & inside & (fetched[..., 4] > 0)
            rel_z_mm = (fetched[..., 3] - depth) * mm_per_unit
            r3 = _safe_sqrt(r * r + rel_z_mm * rel_z_mm)
            rcp_pdf = jnp.where(active, d_max, 0.0) / _exp_sum(jnp.where(active, r / jnp.where(active, d_max, 1.0),
                                                                         0.0))
            weight = shape * _exp_sum(r3[..., None] * shape) * rcp_pdf[..., None]
            weight = jnp.where(ok[..., None], weight, 0.0)
            return total_e + weight * fetched[..., :3], total_w + weight

        zero = jnp.zeros(irradiance.shape, dtype)
        total_e, total_w = jax.lax.fori_loop(0, budget, sample, (zero, zero))
        # the quotient's derivative without the square of the weight total (it underflowed float32 where a pixel's
        # only samples in the frame lie across a depth step: NaN gradients in d; found by a review)
        scattered = jnp.where(total_w > 0, weighted_mean(total_e, jnp.where(total_w > 0, total_w, 1.0)), 0.0)
        local = ~active[..., None] | ~has_d
        return acc + jnp.where(local, irradiance, scattered)

    total = jax.lax.fori_loop(0, frames, one_frame, jnp.zeros(irradiance.shape, dtype))
    return _finish(buffers, prep, put(prep.irradiance, total / frames))


class HdrpPass(AbstractTechnique):
    """HDRP's screen-space subsurface pass (``SubsurfaceScattering.compute``) on sss_jax's buffers.

    ``quality`` low/medium/high is the sample budget 20/40/80; ``budget`` (1..1000) overrides it; ``frames`` averages
    that many TAA frames; ``seed`` turns the per-pixel hash. Takes a ``BurleyMaterial`` (HDRP's profile holds
    Burley's d directly: ``engines.Hdrp``); ``HdrpPass.material_from_engine(params)`` reads a diffusion profile's
    values. An eager call computes only the SSS pixels where they are under half the frame (``_engine_frame.
    compacted_pixels``: HDRP's stencil; the same values as every pixel computed), a traced one every pixel.
    """

    name: ClassVar[str] = "hdrp"
    conserves_energy: ClassVar[bool] = True
    sss_pixels_only: ClassVar[bool] = True
    material_type: ClassVar[type | tuple[type, ...]] = BurleyMaterial

    quality: str = option("medium", "sample budget by quality level (low 20, medium 40, high 80)",
                          choices=tuple(HDRP_QUALITY_BUDGETS))
    budget: int | None = option(None, "explicit sample budget 1..1000 (overrides --quality)")
    frames: int = option(1, "TAA frames averaged, each with its own rotation hash")
    albedo_mode: str = option("post", "texturing mode (post-scatter, or pre-and-post)", choices=ALBEDO_MODES)
    seed: int = option(0, "seed of the per-pixel rotation hash", static=False)

    def __check_init__(self):
        hdrp_budget(self.quality, self.budget)
        check_host_count(self.frames, "hdrp: frames")
        check_seed("hdrp", self.seed)

    @property
    def samples(self) -> int:
        """The budget the pass runs with."""
        return hdrp_budget(self.quality, self.budget)

    def __call__(self, buffers: Buffers, material: BurleyMaterial, camera: Camera, *,
                 origin: tuple[int, int] = (0, 0), frame_shape: tuple[int, int] | None = None,
                 keep: tuple[int, int, int, int] | None = None) -> Float[Array, "H W 3"]:
        """``origin``, ``frame_shape``: the buffer's place in the whole frame (a tile's); ``keep=(row0, col0, rows,
        cols)``: the only pixels of the buffer the caller keeps (a tile's, without its halo): only they are computed
        (the samples still read the whole buffer), the others come back as their local shading."""
        self.check_material(material)
        placed = pass_arguments(self.name, self.albedo_mode, buffers, origin, frame_shape, material.count)
        # only the SSS pixels (HDRP's stencil) where the call can count them, else the kept window or every pixel
        start, size, idx = pixels_to_compute(self.name, buffers, material, camera, keep)
        # the seed (checked when the object was made) as a uint32 array: traced, a sequence's seeds share one
        # program (a Python int would be static); so are a tile's origin and its kept window's corner
        out = _hdrp_impl(buffers, material, camera, self.samples, int(self.frames), self.albedo_mode,
                         _as_seed(self.seed), *placed, start, size, None if idx is None else jnp.asarray(idx))
        # whole frames only: a tile's halo may be black
        if placed[0] is None and keep is None and _is_concrete(buffers, material, camera, out):
            message = black_pixels_message(buffers, out)
            if message is not None:
                warnings.warn(message, SamplingWarning, stacklevel=2)
        return out

    def pieces(self, count: int) -> tuple[tuple["HdrpPass", float], ...] | None:
        """The ``frames`` in about ``count`` calls of consecutive frames (each frame's rotation hashes the seed and
        the frame as ``burley``'s does: ``seed_of_frame``), weighted by their share: a long average runs in pieces
        a batch can show progress between and stop at."""
        from ._burley_technique import seed_of_frame

        return frame_pieces(self, count, seed_of_frame)

    def reach_px(self, buffers: Buffers, material: BurleyMaterial, camera: Camera) -> int:
        """The farthest sample: the radius of sample ``n-1`` (``u = 1 - 0.5/n``) at the nearest SSS pixel."""
        return int(math.ceil(_max_ppm(buffers, camera) * _sample_radius_mm(material, self.samples))) + 1

    @staticmethod
    def material_from_engine(params: dict[str, Any]) -> BurleyMaterial:
        """The ``BurleyMaterial`` HDRP renders for a diffusion profile's values (``engines.Hdrp.from_engine``)."""
        from ..engines import get_engine

        albedo, d = get_engine("hdrp").from_engine(dict(params))
        return BurleyMaterial(albedo, d)


def black_pixels_message(buffers: Buffers, out: Array) -> str | None:
    """Host side: what to say where ``hdrp`` wrote 0 in a channel of an SSS pixel that the input lit: as HDRP does
    (``totalIrradiance / max(totalWeight, FLT_MIN)``) where every sample of the pixel was skipped (off the frame, on
    pixels without SSS) or the channel's weights underflowed in float32; a frame or channel gone black without a
    word read as a bug (a d typed 1e4 instead of 1.4). None where no pixel did."""
    pixels, lit, hit = jax.device_get(_black_counts(buffers, out))  # reduced on the device: five numbers read
    if pixels == 0:
        return None
    channels = "".join(c for c, h in zip("RGB", hit) if h)
    return (f"hdrp: {int(pixels)} of {int(lit)} lit SSS pixels came out black in "
            f"{channels}: every sample of theirs landed off the frame or on pixels without SSS, or the channel's "
            f"weights underflowed in float32 (a d far below the widest channel's): what HDRP's pass renders there "
            f"(burley keeps the pixel's own light)")


@jax.jit
def _black_counts(buffers: Buffers, out: Array) -> tuple[Array, Array, Array]:
    """``black_pixels_message``'s counts: SSS pixels black in some channel the input lit, the lit SSS pixels, and
    which channels went black (3,). (Read to the host whole, the images cost ~5 ms of a 640x360 call.)"""
    lit = _sss_mask(buffers)[..., None] & (buffers.irradiance > 0)
    black = lit & (out == 0)
    return jnp.count_nonzero(black.any(axis=-1)), jnp.count_nonzero(lit.any(axis=-1)), black.any(axis=(0, 1))


def _max_ppm(buffers: Buffers, camera: Camera) -> float:
    z = np.asarray(buffers.depth, np.float64)
    ok = np.isfinite(z) & (z > 0)
    if not ok.any():
        return 0.0
    return float(camera.focal_px) / (float(np.min(z[ok])) * float(camera.mm_per_unit))


def _sample_radius_mm(material: BurleyMaterial, n: int) -> float:
    # the inverse CCDF scales with d: r(v, d) = d r(v, 1)
    return float(np.max(np.asarray(material.d_mm, np.float64))) * unit_radius(0.5 / n)


def hdrp(buffers: Buffers, material: BurleyMaterial, camera: Camera, **options) -> Float[Array, "H W 3"]:
    """HDRP's own subsurface pass: ``HdrpPass(**options)(buffers, material, camera)`` (see ``HdrpPass``)."""
    return built(HdrpPass, options)(buffers, material, camera)
