"""Jimenez et al.'s separable SSS pass, as the shader executes it (``jimenez`` technique).

iryoku/separable-sss ``SeparableSSS.h`` ``SSSSBlurPS`` and ``Demo/Code/SeparableSSS.cpp`` ``calculateKernel``: a
horizontal then a vertical pass of the ``calculateKernel`` taps (17 at ``SSSS_QUALITY`` 1, 25 at 2, 11 at 0),
centre tap first:

- ``finalStep = sssWidth * (1 / tan(fovy/2)) / depth * dir * alpha / 3`` in texture coordinates, so the horizontal
  pass (``dir = (1, 0)``, ``W`` pixels per unit) reaches ``W/H`` times farther in pixels than the vertical one;
- each tap is a bilinear fetch (``LinearSampler``: linear filter, Clamp address mode, so a tap off the frame reads
  the edge texel); the comb of taps is what the pass applies, not the kernel spread over its footprints;
- follow the surface: ``s = saturate(300 / tan(fovy/2) * sssWidth * |depth_centre - depth_tap|)`` and the tap's
  colour becomes ``lerp(tap, centre, s)`` (the rule reads the field of view, not the kernel's reach);
- ``out = kernel[0] centre + sum kernel[i] tap_i``.

``fovy`` is the camera's: ``tan(fovy/2) = (frame height / 2) / focal_px``. Only pixels with SSS are written (the
stencil): the horizontal pass reads the colour target, whose pixels without SSS hold their light as given, and writes
a temporary target cleared to black (``SeparableSSS::go``), which the vertical pass reads: there a tap on a pixel
without SSS reads black (pulled towards the centre by the follow-surface rule where its depth differs). A pixel
without a surface reads as depth ``_FAR`` (the follow-surface rule saturates there). Parameters: the engine's
``JimenezParams`` directly, or a ``BurleyMaterial`` converted on the host by ``engines.Jimenez.to_engine`` (the
least-squares fit of its kernel to Burley's; not traced, so gradients flow through ``JimenezParams`` only).
"""

from __future__ import annotations

import functools
import math
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._materials import BurleyMaterial
from .._scene import Buffers, Camera, surface_mask
from ._base import AbstractTechnique, built, option
from ._common import (
    ALBEDO_MODES,
    _check_albedo_mode,
    _finish,
    _prepare,
    _work_dtype,
    check_one_image,
)
from ._engine_frame import placement

JIMENEZ_TAPS = (11, 17, 25)  # SeparableSSS.h: SSSS_N_SAMPLES for SSSS_QUALITY 0, 1, 2
_FAR = 1e20
# SeparableSSS::profile: d'Eon's skin fit without its narrowest Gaussian (as engines._jimenez._JIMENEZ_PROFILE)
_PROFILE = ((0.100, 0.0484), (0.118, 0.187), (0.113, 0.567), (0.358, 1.99), (0.078, 7.41))


class JimenezParams(eqx.Module):
    """The separable-SSS shader's parameters: ``albedo`` (3,) (the texture's), ``strength`` (3,) and ``falloff`` (3,)
    in [0, 1], ``sss_width`` (scene units, the shader's ``sssWidth``) and the colour target's ``alpha``
    (``SSSS_STREGTH_SOURCE``, scales the width)."""

    albedo: Float[Array, "1 3"]
    strength: Float[Array, "3"]
    falloff: Float[Array, "3"]
    sss_width: Float[Array, ""]
    alpha: Float[Array, ""]

    def __init__(self, *, strength, falloff, sss_width, albedo=(1.0, 1.0, 1.0), alpha=1.0):
        self.strength = jnp.asarray(strength, jnp.result_type(float)) * jnp.ones(3)
        self.falloff = jnp.asarray(falloff, self.strength.dtype) * jnp.ones(3, self.strength.dtype)
        self.albedo = jnp.reshape(jnp.asarray(albedo, self.strength.dtype) * jnp.ones(3, self.strength.dtype), (1, 3))
        self.sss_width = jnp.asarray(sss_width, self.strength.dtype)
        self.alpha = jnp.asarray(alpha, self.strength.dtype)

    def __check_init__(self):
        for name, lo, hi in (("strength", 0.0, 1.0), ("falloff", 0.0, 1.0), ("albedo", 0.0, 1.0),
                             ("alpha", 0.0, 1.0)):
            v = getattr(self, name)
            if not isinstance(v, jax.core.Tracer) and not np.all((np.asarray(v) >= lo) & (np.asarray(v) <= hi)):
                raise ValueError(f"JimenezParams {name} must be within [{lo}, {hi}], got {np.asarray(v).tolist()}")
        if not isinstance(self.sss_width, jax.core.Tracer) and not 0 <= float(self.sss_width) < math.inf:
            raise ValueError(f"JimenezParams sss_width must be finite and >= 0 (scene units), got "
                             f"{float(self.sss_width)}")

    @classmethod
    def from_engine(cls, params: dict[str, Any]) -> "JimenezParams":
        """From the engine block's names (``sssWidth``, ``strength``, ``falloff``, ``alpha``, ``albedo``)."""
        for key in ("sssWidth", "strength", "falloff"):
            if key not in params:
                raise ValueError(f"jimenez parameters need {key!r}")
        return cls(strength=params["strength"], falloff=params["falloff"], sss_width=params["sssWidth"],
                   albedo=params.get("albedo", (1.0, 1.0, 1.0)), alpha=params.get("alpha", 1.0))


def jimenez_kernel_jax(strength: Array, falloff: Array, taps: int) -> tuple[Array, Array]:
    """``calculateKernel`` traced: offsets (taps,) in kernel units and weights (taps, 3), centre tap first."""
    dtype = strength.dtype
    rng = 3.0 if taps > 20 else 2.0
    step = 2.0 * rng / (taps - 1)
    o = -rng + jnp.arange(taps, dtype=dtype) * step
    offsets = rng * jnp.sign(o) * o * o / (rng * rng)  # exponent 2
    gaps = jnp.abs(jnp.diff(offsets))
    area = (jnp.concatenate([jnp.zeros(1, dtype), gaps]) + jnp.concatenate([gaps, jnp.zeros(1, dtype)])) / 2
    rr = offsets[:, None] / (0.001 + falloff[None, :])
    profile = sum(wt * jnp.exp(-(rr * rr) / (2.0 * v)) / (2.0 * 3.14 * v) for wt, v in _PROFILE)
    weights = area[:, None] * profile
    order = np.r_[taps // 2, np.delete(np.arange(taps), taps // 2)]
    offsets, weights = offsets[order], weights[order]
    weights = weights / jnp.sum(weights, axis=0, keepdims=True)
    weights = jnp.concatenate([(1.0 - strength + strength * weights[0])[None], weights[1:] * strength[None, :]], axis=0)
    return offsets, weights


@functools.lru_cache(maxsize=64)
def _fitted(albedo: tuple, d_mm: tuple, mm_per_unit: float, taps: int) -> dict[str, Any]:
    from ..engines import get_engine

    return get_engine("jimenez").to_engine(np.array(albedo), np.array(d_mm), mm_per_unit=mm_per_unit, n_samples=taps)


def jimenez_params_for(material: BurleyMaterial, camera: Camera, taps: int) -> JimenezParams:
    """The engine parameters ``engines.Jimenez.to_engine`` fits for a one-row ``BurleyMaterial`` (host side)."""
    if any(isinstance(x, jax.core.Tracer) for x in (material.albedo, material.d_mm, camera.mm_per_unit)):
        raise TypeError("jimenez fits its parameters to a BurleyMaterial on the host (scipy), which a traced material "
                        "cannot give: trace JimenezParams instead (jimenez_params_for(material, camera, taps) "
                        "outside jit)")
    if material.count != 1:
        raise ValueError(f"jimenez takes one material (the shader has one kernel), got {material.count}")
    # the host reads the whole arrays and indexes them in NumPy: ``material.albedo[0]`` would be a JAX operation,
    # which a trace around the call (a material closed over under ``jit``) stages as a tracer
    albedo = tuple(float(v) for v in np.asarray(material.albedo, np.float64).reshape(-1, 3)[0])
    d = tuple(float(v) for v in np.asarray(material.d_mm, np.float64).reshape(-1, 3)[0])
    block = _fitted(albedo, d, float(camera.mm_per_unit), int(taps))
    return JimenezParams.from_engine(block)


def _linear_clamp_1d(values: Array, pos: Array, axis: int) -> Array:
    """Bilinear fetch along ``axis`` at fractional pixel ``pos`` (pixel centres at integers) with Clamp addressing:
    ``values (H, W, K)``, ``pos (H, W)``."""
    n = values.shape[axis]
    # Clamp addressing reads the edge pixel anywhere past it: a position held within [-1, n] fetches the same, and
    # one that overflowed to +-inf (a huge step) fetches the edge instead of inf - inf = NaN
    pos = jnp.clip(pos, -1.0, n)
    p0 = jnp.floor(pos)
    f = (pos - p0)[..., None]
    i0 = jnp.clip(p0, 0, n - 1).astype(jnp.int32)
    i1 = jnp.clip(p0 + 1, 0, n - 1).astype(jnp.int32)
    if axis == 1:
        rows = jnp.arange(values.shape[0])[:, None]
        a, b = values[rows, i0], values[rows, i1]
    else:
        cols = jnp.arange(values.shape[1])[None, :]
        a, b = values[i0, cols], values[i1, cols]
    # a + f (b - a), not (1 - f) a + f b: exact where a == b (a flat plane's depth), which the fused float32 form
    # was not by an ulp, and 300 / tan x width x that ulp pulled taps to the centre on a plane 3 m away (a review)
    return a + f * (b - a)


@eqx.filter_jit
def _jimenez_impl(buffers: Buffers, params: JimenezParams, camera: Camera, taps: int, follow_surface: bool,
                  albedo_mode: str, frame_shape) -> Array:
    dtype = _work_dtype(buffers.irradiance.dtype)
    prep = _prepare(buffers, params.albedo, albedo_mode, dtype)
    h, w = buffers.depth.shape
    fh, fw = (h, w) if frame_shape is None else frame_shape  # a texture coordinate spans the frame
    focal = camera.focal_px.astype(dtype)
    inv_tan = 2.0 * focal / fh  # 1 / tan(fovy / 2)
    surface = surface_mask(buffers.depth)
    depth = jnp.where(surface, buffers.depth.astype(dtype), _FAR)
    # what the colour target holds: the scattered light on SSS pixels, anything else as it is (finite)
    raw = buffers.irradiance.astype(dtype)
    colour = jnp.where(prep.valid[..., None], prep.irradiance, jnp.where(jnp.isfinite(raw), raw, 0.0))
    offsets, weights = jimenez_kernel_jax(params.strength.astype(dtype), params.falloff.astype(dtype), taps)
    width = params.sss_width.astype(dtype)
    spread = width * params.alpha.astype(dtype)
    # finalStep, texture coordinates; no width or no alpha is no step, even where inv_tan / depth overflowed
    step_uv = jnp.where(spread > 0, spread * inv_tan / depth / 3.0, 0.0)
    steps = (step_uv * fw, step_uv * fh)  # as pixels: a texture coordinate spans W (horizontal) or H pixels
    depth_c = depth[..., None]
    pos0 = (jnp.broadcast_to(jnp.arange(w, dtype=dtype)[None, :], (h, w)),
            jnp.broadcast_to(jnp.arange(h, dtype=dtype)[:, None], (h, w)))
    stacked = jnp.concatenate([colour, depth_c], axis=-1)

    def one_pass(source, axis, step):
        centre = source[..., :3]
        base = pos0[0 if axis == 1 else 1]

        def add_tap(i, out):
            fetched = _linear_clamp_1d(source, base + offsets[i] * step, axis)
            tap = fetched[..., :3]
            if follow_surface:
                gap = jnp.abs(depth - fetched[..., 3])
                # no gap (or no width) is no pull, also where the product overflowed (inf x 0 would be NaN)
                s = jnp.where((gap > 0) & (width > 0), jnp.clip(300.0 * inv_tan * width * gap, 0.0, 1.0),
                              0.0)[..., None]
                tap = tap + s * (centre - tap)
            return out + weights[i][None, None, :] * tap

        # the taps in a loop, summed in the shader's order: unrolled, the program held every tap's fetch at once
        # (1,056 bytes of scratch a pixel at 17 taps against 96: 1.9 GB above the frame's at 1920x1080, 9.4 GB peak
        # at 3840x2160)
        out = jax.lax.fori_loop(1, taps, add_tap, weights[0][None, None, :] * centre)
        return jnp.where(prep.valid[..., None], out, centre)

    # the horizontal pass writes a target cleared to black (``SeparableSSS::go``: ``tmpRT``), and only where the
    # stencil passes: the vertical pass reads 0 on every pixel without SSS, not its light
    horizontal = jnp.where(prep.valid[..., None], one_pass(stacked, 1, steps[0]), 0.0)
    vertical = one_pass(jnp.concatenate([horizontal, depth_c], axis=-1), 0, steps[1])
    return _finish(buffers, prep, vertical)


class JimenezPass(AbstractTechnique):
    """Jimenez et al.'s separable SSS shader (``SSSSBlurPS``) on sss_jax's buffers: ``taps`` 11/17/25, the
    follow-surface rule on or off. Takes ``JimenezParams`` (the shader's own) or a ``BurleyMaterial`` (fitted by
    ``engines.Jimenez``)."""

    name: ClassVar[str] = "jimenez"
    conserves_energy: ClassVar[bool] = True
    material_type: ClassVar[type | tuple[type, ...]] = (BurleyMaterial, JimenezParams)

    taps: int = option(17, "kernel taps (SSSS_N_SAMPLES: 11, 17 or 25)", choices=JIMENEZ_TAPS)
    follow_surface: bool = option(True, "SSSS_FOLLOW_SURFACE (lerp taps across depth steps to the centre)",
                                  choices=(True, False))
    albedo_mode: str = option("post", "albedo applied after the scatter, or split before and after",
                              choices=ALBEDO_MODES)

    def traces_camera(self, material) -> bool:
        # a BurleyMaterial's shader parameters are fitted on the host at the camera's scene unit
        return not isinstance(material, BurleyMaterial)

    def params(self, material, camera: Camera) -> JimenezParams:
        """The shader parameters the pass runs with for ``material``."""
        self.check_material(material)
        if isinstance(material, JimenezParams):
            return material
        return jimenez_params_for(material, camera, self.taps)

    def __call__(self, buffers: Buffers, material, camera: Camera, *, origin: tuple[int, int] = (0, 0),
                 frame_shape: tuple[int, int] | None = None) -> Float[Array, "H W 3"]:
        _check_albedo_mode(self.albedo_mode)
        check_one_image("jimenez", buffers, getattr(material, "count", None), camera=camera)
        params = self.params(material, camera)
        # the pass reads only the frame's size: every tile of one shape is one program, wherever it lies
        _, frame_shape = placement(buffers.depth.shape, origin, frame_shape)
        return _jimenez_impl(buffers, params, camera, int(self.taps), bool(self.follow_surface), self.albedo_mode,
                             frame_shape)

    def reach_px(self, buffers: Buffers, material, camera: Camera, *, frame_shape=None) -> int:
        """Both passes' farthest taps (the outermost kernel offset, the horizontal one W/H wider) at the nearest
        surface, plus one for the bilinear fetch."""
        p = self.params(material, camera)
        h, w = frame_shape or buffers.depth.shape
        z = np.asarray(buffers.depth, np.float64)
        ok = np.isfinite(z) & (z > 0)
        if not ok.any():
            return 0
        rng = 3.0 if self.taps > 20 else 2.0
        step = float(p.sss_width) * float(p.alpha) * 2 * float(camera.focal_px) / h / float(np.min(z[ok])) / 3.0
        return int(math.ceil(rng * step * max(w, h))) + 2


def jimenez(buffers: Buffers, material, camera: Camera, **options) -> Float[Array, "H W 3"]:
    """Jimenez's separable SSS shader: ``JimenezPass(**options)(buffers, material, camera)``."""
    return built(JimenezPass, options)(buffers, material, camera)
