"""What one pixel of a technique costs as a shader (the engine's, for the engines' passes) executes it: texels read
and arithmetic, counted from the formulation, the same on every machine.

Wall times differ by orders of magnitude between a laptop's CPU and a GPU, and a jitted JAX pass does not execute an
engine's loop the way the engine does (HDRP's pass loops over ``n = min(area / 4, budget)`` samples per pixel; its
JAX formulation runs the budget on every pixel, masked). These counts are what the engine's shader executes per SSS
pixel and frame, so a report or the bench reads the same on any machine. ``frame_cost(technique, buffers,
material, camera)`` asks the frame (footprints, depth) where the count depends on it; ``cost_per_pixel(name,
count, interpolation)`` is the count-only model of the bench's grid.

Counting rules (each an estimate of the shader's instructions, kept in one place): an add, a multiply, a compare,
a select or a transcendental each count one, a fused multiply-add two. ``fetches``: texels read, each RGB + depth
(a point fetch reads 1, a linear fetch along one axis 2, a bilinear 2D fetch 4).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["cost_per_pixel", "frame_cost"]

# Arithmetic per pixel of the pieces of a pass, counted from the formulation (``_techniques/_separable_spec.tap_sums``
# and ``pass_value``, ``_techniques/_burley_spec``), not measured.
# separable per tap: offset (mul, clip), its corner(s) (floor, sub), the weighted sums A and K (3 x 2 FMA)
_SEPARABLE_FLOPS_PER_TAP = 4 + 3 * 2 * 2
# per fetched pixel: follow the surface (sub, abs, mul, sub, max), validity (1), frac (1), 3 x (mul, add) into the
# tap's kept light, one add into its kept weight
_SEPARABLE_FLOPS_PER_FETCH = 5 + 1 + 1 + 3 * 2 + 1
_BURLEY_FLOPS_PER_SAMPLE = 30  # inverse CCDF (~12 with log, sqrt, exp), sin/cos and position (6), 1/pdf (5), corners
_BURLEY_FLOPS_PER_FETCH = 33  # validity (3), dz (2), r (3 with sqrt), 3 x kernel (exp, 2 mul, FMA, div), num/den (9)
_STA_COST = {"fetches": 4, "flops": 40}  # irradiance, normal, thickness, albedo; the transmittance and the light
# HDRP (SubsurfaceScattering.compute EvaluateSample, as _techniques/_hdrp.py ports it): u (2), the widest channel's
# inverse CDF (~12), angle (frac, mul, add: 3), sin/cos (2), offset and round (4), validity (3), dz (2), the 3D
# distance (3 with sqrt), 1/pdf (exp sum ~5, div), 3 x profile at the distance (mul, exp sum ~5, 2 mul: 8), 3 x
# accumulate colour and weight (FMA + add: 3)
_HDRP_FLOPS_PER_SAMPLE = 2 + 12 + 3 + 2 + 4 + 3 + 2 + 3 + 6 + 3 * 8 + 3 * 3
# EEVEE Next (eevee_subsurface_convolve_comp.glsl, as _techniques/_eevee_next.py ports it): rotate and scale the
# sample (8), round (4), validity (2), view-space dx, dy, dz (10), distance (6 with sqrt), 3 x burley_eval (exp,
# cube, add, 2 mul: 6), 3 x pdf and accumulate (mul, FMA, add: 4)
_EEVEE_FLOPS_PER_SAMPLE = 8 + 4 + 2 + 10 + 6 + 3 * 6 + 3 * 4
# Jimenez (SeparableSSS.h SSSSBlurPS): offset (FMA: 2), the linear fetch's lerp of RGB + depth (4 x FMA: 8, floor and
# frac: 2), follow the surface (sub, abs, mul, saturate: 4; 3 x lerp: 6), 3 x kernel-weighted add (FMA: 6)
_JIMENEZ_FLOPS_PER_TAP = 2 + 8 + 2 + 4 + 6 + 6
_JIMENEZ_FLOPS_PER_TAP_FLAT = 2 + 8 + 2 + 6  # SSSS_FOLLOW_SURFACE 0: no depth test, no lerp

# pixels a filtered fetch reads (bilinear 2D: 4; a linear 1D fetch: 2) by registry name
_PIXELS_PER_FETCH = {"burley": 4}
_PASSES = {"separable": 2}  # the 1D passes a count runs in, each its own taps and centre
_COST_MODELS: dict[str, Callable[[int | None, int], dict[str, int]]] = {
    "sta": lambda count, per_fetch: dict(_STA_COST),
    # the centre tap is the pixel's own value (one fetch, its weight: 3 products), not a filtered fetch: it was
    # counted a second time as a tap, 38 / 70 / 102 fetches for 9 / 17 / 25 taps where the pass reads 34 / 66 / 98
    "separable": lambda count, per_fetch: {
        "fetches": _PASSES["separable"] * ((count - 1) * per_fetch + 1),
        "flops": _PASSES["separable"] * ((count - 1) * (_SEPARABLE_FLOPS_PER_TAP
                                                        + per_fetch * _SEPARABLE_FLOPS_PER_FETCH) + 3)},
    "burley": lambda count, per_fetch: {
        "fetches": count * per_fetch + 1,
        "flops": count * _BURLEY_FLOPS_PER_SAMPLE + count * per_fetch * _BURLEY_FLOPS_PER_FETCH},
}


def cost_per_pixel(technique: str, count: int | None, interpolation: str = "linear") -> dict[str, int]:
    """Engine-comparable cost of one pixel of the technique: ``fetches`` (texels read, each RGB + depth, what a
    shader's texture fetches are) and ``flops`` (arithmetic per pixel, counted from the formulation). The same on
    every machine, so the trade reads the same where wall times differ by orders of magnitude.

    separable: 2 passes x ``count - 1`` taps x (2 pixels per linear fetch, 1 nearest), plus the centre per pass.
    burley: ``count`` samples x (4 pixels per bilinear fetch, 1 nearest), plus the centre."""
    model = _COST_MODELS.get(technique)
    if model is not None:
        return model(count, 1 if interpolation == "nearest" else _PIXELS_PER_FETCH.get(technique, 2))
    raise ValueError(f"no cost model for technique {technique!r}; models for: {', '.join(_COST_MODELS)}")


# ------------------------------------------------------------------------------------------------------------------
# per frame: what the shader executes on this frame's SSS pixels (the count may depend on each pixel's footprint)
# ------------------------------------------------------------------------------------------------------------------

def _sss_pixels(buffers) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mask of SSS pixels, their depth, their material row index) on the host."""
    depth = np.asarray(buffers.depth, np.float64)
    ids = (np.asarray(buffers.material_id) if buffers.material_id is not None
           else np.ones(depth.shape, np.int32))
    mask = (ids > 0) & np.isfinite(depth) & (depth > 0)
    return mask, depth[mask], np.maximum(ids[mask].astype(np.int64) - 1, 0)


def _rows(values, rows: np.ndarray) -> np.ndarray:
    table = np.asarray(values, np.float64).reshape(-1, 3)
    return table[np.minimum(rows, table.shape[0] - 1)] if table.shape[0] > 1 else np.broadcast_to(
        table[0], (rows.size, 3))


def _per_mm(camera, depth: np.ndarray) -> np.ndarray:
    """Pixels per mm at each depth (``_units.px_per_mm``'s formula on the host)."""
    return float(camera.focal_px) / (depth * float(camera.mm_per_unit))


def _summary(samples: np.ndarray, fetches: np.ndarray, flops: np.ndarray, active: np.ndarray, frames: int,
             rule: str) -> dict[str, Any]:
    n = max(int(samples.size), 1)
    return {"samples": round(float(samples.sum()) / n, 2), "fetches": round(float(fetches.sum()) / n, 2),
            "flops": round(float(flops.sum()) / n, 1), "active_fraction": round(float(active.sum()) / n, 4),
            "frames": int(frames), "rule": rule}


def _count_cost(t, buffers, material, camera, active=None) -> dict[str, Any]:
    """separable and burley: the count model on every pixel the pass computes (``active``: the pixels it computes;
    the others keep their own irradiance, one fetch)."""
    count = int(getattr(t, t.count_option))
    interpolation = getattr(t, "interpolation", "linear")
    model = cost_per_pixel(t.name, count, interpolation)
    _, depth, _ = _sss_pixels(buffers)
    active = np.ones(depth.shape, bool) if active is None else active
    passes = _PASSES.get(t.name, 1)  # separable's taps run once per pass, as jimenez's are counted
    samples = np.where(active, passes * count, 0).astype(np.float64)
    fetches = np.where(active, model["fetches"], 1).astype(np.float64)
    flops = np.where(active, model["flops"], 0).astype(np.float64)
    per_pass = f"{passes} passes x " if passes > 1 else ""
    return _summary(samples, fetches, flops, active, getattr(t, "frames", 1),
                    f"{per_pass}{count} {t.count_option} per pixel ({interpolation} fetches)")


def _burley_cost(t, buffers, material, camera) -> dict[str, Any]:
    """Burley: the count model on the pixels whose 99%-energy radius reaches ``min_footprint_px``."""
    from ._techniques._burley_spec import BURLEY_R99

    _, depth, rows = _sss_pixels(buffers)
    d_px = _rows(material.d_mm, rows).max(-1) * _per_mm(camera, depth)
    return _count_cost(t, buffers, material, camera, active=d_px * BURLEY_R99 >= float(t.min_footprint_px))


def _separable_cost(t, buffers, material, camera) -> dict[str, Any]:
    """separable: the count model on the pixels whose kernel reaches ``min_footprint_px`` (``Separable.reach_px``'s
    rule: the outermost tap's offset in px at the pixel's depth); the others keep their local shading (they were all
    counted as computed: a material 64x narrower cost 38 fetches a pixel where the pass computed none)."""
    from ._techniques._separable_technique import kernel_reach_mm

    _, depth, rows = _sss_pixels(buffers)
    reach_mm = kernel_reach_mm(material, int(t.taps))
    reach_px = reach_mm[np.minimum(rows, reach_mm.shape[0] - 1)] * _per_mm(camera, depth)
    return _count_cost(t, buffers, material, camera,
                       active=(reach_px >= float(t.min_footprint_px)) & (reach_px > 0))


def _sta_cost(t, buffers, material, camera) -> dict[str, Any]:
    mask, depth, _ = _sss_pixels(buffers)
    ones = np.ones(depth.shape)
    return _summary(0 * ones, _STA_COST["fetches"] * ones, _STA_COST["flops"] * ones, ones > 0, 1,
                    "local: irradiance, normal, thickness, albedo")


def _hdrp_cost(t, buffers, material, camera) -> dict[str, Any]:
    """HDRP: ``n = min(floor(pi r^2 / 4), budget)`` point fetches per pixel, ``r`` the filter radius in px (0.997
    of the widest channel's energy); ``n < 1`` keeps the pixel (one fetch)."""
    from ._techniques._hdrp import FILTER_RADIUS_UNITS, HDRP_PIXELS_PER_SAMPLE

    _, depth, rows = _sss_pixels(buffers)
    filter_px = FILTER_RADIUS_UNITS * _rows(material.d_mm, rows).max(-1) * _per_mm(camera, depth)
    n = np.minimum(np.floor(np.pi * filter_px ** 2 / HDRP_PIXELS_PER_SAMPLE), t.samples)
    active = n >= 1
    samples = np.where(active, n, 0.0)
    return _summary(samples, samples + 1, samples * _HDRP_FLOPS_PER_SAMPLE, active, t.frames,
                    f"min(area / {HDRP_PIXELS_PER_SAMPLE} px, budget {t.samples}) point fetches per pixel")


def _eevee_next_cost(t, buffers, material, camera) -> dict[str, Any]:
    """EEVEE Next: 16 point fetches per pixel and TAA frame where the kernel's scale exceeds a pixel."""
    from ._techniques._eevee_next import EEVEE_SAMPLE_LEN

    _, depth, rows = _sss_pixels(buffers)
    albedo = np.clip(_rows(material.albedo, rows), 0.0, 1.0)
    # s(A) of the albedo normalised by its largest channel (engines.EeveeNext; _eevee_next._s_normalised on the host)
    a = albedo / np.maximum(1e-6, albedo.max(-1, keepdims=True))
    s = 1.9 - a + 3.5 * (a - 0.8) ** 2
    radius = (_rows(material.d_mm, rows) * 4 * np.pi * s).max(-1)
    active = radius * _per_mm(camera, depth) > 1.0
    samples = np.where(active, float(EEVEE_SAMPLE_LEN), 0.0)
    return _summary(samples, samples + 1, samples * _EEVEE_FLOPS_PER_SAMPLE, active, t.frames,
                    f"{EEVEE_SAMPLE_LEN} point fetches per pixel and TAA frame (scale > 1 px)")


def _jimenez_cost(t, buffers, material, camera) -> dict[str, Any]:
    """Jimenez: two passes of the centre (a point fetch) and ``taps - 1`` linear fetches along the pass (2 texels,
    colour and depth), on every SSS pixel (the stencil)."""
    _, depth, _ = _sss_pixels(buffers)
    taps = int(t.taps)
    per_tap = _JIMENEZ_FLOPS_PER_TAP if t.follow_surface else _JIMENEZ_FLOPS_PER_TAP_FLAT
    ones = np.ones(depth.shape)
    return _summary(2.0 * taps * ones, 2.0 * (1 + 2 * (taps - 1)) * ones, 2.0 * (taps - 1) * per_tap * ones + 6,
                    ones > 0, 1, f"2 passes x ({taps - 1} linear fetches + the centre)")


# by registry name: a technique added to the cost models adds a row, not a branch
_FRAME_COSTS: dict[str, Callable[..., dict[str, Any]]] = {
    "separable": _separable_cost, "burley": _burley_cost, "sta": _sta_cost, "hdrp": _hdrp_cost,
    "eevee-next": _eevee_next_cost, "jimenez": _jimenez_cost,
}


def frame_cost(technique, buffers, material, camera) -> dict[str, Any] | None:
    """What ``technique`` (an object) costs per SSS pixel and frame as its shader executes it on these buffers:
    ``samples`` (taps or samples per pixel), ``fetches`` (texels read, each RGB + depth), ``flops``, the mean over
    the frame's SSS pixels; ``active_fraction`` (pixels the pass computes rather than passes through), ``frames``
    (TAA frames the run averages: each costs this again) and the ``rule`` counted. None for a technique without a
    cost model (the reference: a dense window, not a real-time pass)."""
    model = _FRAME_COSTS.get(technique.name)
    if model is None:
        return None
    mask, _, _ = _sss_pixels(buffers)
    if not mask.any():
        return None
    return model(technique, buffers, material, camera)
