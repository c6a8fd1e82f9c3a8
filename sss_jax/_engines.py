"""One material in every engine's units: conversions between sss_jax's Burley material and production engines.

sss_jax's material is a surface albedo ``A`` (3,) in [0, 1] and Burley's scattering distance ``d_mm`` (3,) in mm,
the ``d`` of ``R(r) = A (exp(-r/d) + exp(-r/(3d))) / (8 pi d r)``. Each engine names that physics differently; the
formulas below were read from each engine's own source, cited beside the code (repository and path). Where an engine
cannot represent the material exactly, the conversion says so (``LOSSY``) and ``engine_profile_error`` measures how
far the engine's rendered kernel is from the Burley reference.

All conversions are host-side NumPy in float64 (they are not traced); the s(A) fits are the ones in ``_profiles``.

| engine | parameters (UI names) | d from them |
|---|---|---|
| ``blender`` (Cycles, Christensen–Burley) | Subsurface Color, Subsurface Radius (scene units), Subsurface Scale | ``d = radius scale mm_per_unit / (4 pi)`` (Cycles >= 3.0); ``/ s_dt(A)`` too in 2.80–2.93 |
| ``eevee`` (legacy, 2.80–4.1) | same node | ``d = 0.6 radius scale mm_per_unit / (4 pi s_dt(1))`` (albedo ignored) |
| ``hdrp`` (Unity) | Scattering Color, Multiplier, World Scale, Base Color | ``d = color multiplier mm_per_unit / (1000 world_scale)`` |
| ``unreal`` (UE5 Burley) | Surface Albedo, Mean Free Path Color, Mean Free Path Distance (cm), World Unit Scale | ``d = 10 mfp_cm / (0.6 s_perp(A))`` kernel mm, times ``world_unit_scale mm_per_unit / 10`` |
| ``jimenez`` (separable SSS) | sssWidth, strength, falloff | none in closed form: fitted (see ``burley_to_jimenez``) |
"""

from __future__ import annotations

import math
from typing import Any

import jax
import numpy as np

from ._profiles import SCALING_FITS, burley_cdf, burley_inverse_cdf

__all__ = [
    "ENGINES",
    "LOSSY",
    "blender_to_burley",
    "burley_to_blender",
    "burley_to_eevee",
    "burley_to_hdrp",
    "burley_to_jimenez",
    "burley_to_unreal",
    "convert",
    "eevee_to_burley",
    "engine_blocks",
    "engine_marginals",
    "engine_profile_error",
    "from_engine",
    "hdrp_to_burley",
    "jimenez_kernel",
    "jimenez_to_burley",
    "to_engine",
    "unreal_to_burley",
]

ENGINES = ("sss_jax", "blender", "eevee", "hdrp", "unreal", "jimenez")

# Which engines cannot hold an arbitrary sss_jax material exactly (A -> engine -> A differs), and why.
LOSSY = {
    "sss_jax": None,
    "blender": None,
    "eevee": "EEVEE legacy evaluates s(A) at a fixed A = 1: the radius that gives this d in EEVEE gives another d in "
             "Cycles; its kernel is the radial profile used as a 1D separable kernel (see engine_profile_error)",
    "hdrp": None,
    "unreal": "exact unless a component of Surface Albedo or Mean Free Path Color is below UE's clamp of 0.009 or the "
              "diffuse mean free path exceeds its 500 mm encoding range",
    "jimenez": "not physical: one d'Eon skin profile shape shared by all channels, scaled by falloff and blended with a "
               "Dirac by strength; the parameters are a least-squares fit to the Burley kernel",
}

_FOUR_PI = 4.0 * math.pi


def _s(fit: str, albedo) -> np.ndarray:
    """The memo's s(A) fit from ``_profiles``, evaluated in float64 whatever the global x64 setting."""
    with jax.enable_x64(True):
        return np.asarray(SCALING_FITS[fit](np.asarray(albedo, np.float64)), np.float64)


def _rgb(name: str, value, *, lo: float | None = 0.0, hi: float | None = None, positive: bool = False) -> np.ndarray:
    """A per-channel parameter as float64 (3,), with its range checked; the error names the parameter."""
    try:
        v = np.broadcast_to(np.asarray(value, np.float64), (3,)).copy()
    except (ValueError, TypeError):
        raise ValueError(f"{name} must be one number or three (R,G,B), got {value!r}") from None
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be finite, got {v.tolist()}")
    if positive and not np.all(v > 0):
        raise ValueError(f"{name} must be > 0, got {v.tolist()}")
    if lo is not None and not np.all(v >= lo):
        raise ValueError(f"{name} must be >= {lo}, got {v.tolist()}")
    if hi is not None and not np.all(v <= hi):
        raise ValueError(f"{name} must be <= {hi}, got {v.tolist()}")
    return v


def _scalar(name: str, value, *, positive: bool = True) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or (positive and not v > 0):
        raise ValueError(f"{name} must be a finite {'positive ' if positive else ''}number, got {value!r}")
    return v


def _material(albedo, d_mm) -> tuple[np.ndarray, np.ndarray]:
    return _rgb("albedo", albedo, lo=0.0, hi=1.0), _rgb("d_mm", d_mm, lo=0.0)


# ----------------------------------------------------------------------------------------------------------------
# Blender: Cycles and EEVEE legacy
# ----------------------------------------------------------------------------------------------------------------

CYCLES_VERSIONS = ("3.0+", "2.8")


def blender_to_burley(subsurface_color, subsurface_radius, *, subsurface_scale: float = 1.0,
                      mm_per_unit: float = 1000.0, cycles: str = "3.0+") -> tuple[np.ndarray, np.ndarray]:
    """(albedo, d_mm) that Cycles' Christensen–Burley renders for a Principled BSDF.

    ``subsurface_radius`` (3,) is in scene units, ``mm_per_unit`` the scene unit in mm (Blender's default metre:
    1000). The closure radius is ``radius * scale`` (blender/blender ``intern/cycles/kernel/svm/closure.h``:
    ``bssrdf->radius = subsurface_radius * subsurface_scale``), then:

    - ``cycles="3.0+"``: ``bssrdf_setup_radius`` multiplies it by ``0.25 * M_1_PI_F`` for
      ``CLOSURE_BSSRDF_BURLEY_ID`` and ``bssrdf_eval``/``bssrdf_sample`` use the result as Burley's d directly
      (``intern/cycles/kernel/closure/bssrdf.h``; ``bssrdf_burley_setup`` with its s(A) is still defined there but
      no longer called): ``d = radius scale / (4 pi)``.
    - ``cycles="2.8"`` (2.80–2.93): ``bssrdf_burley_setup`` divides by the diffuse-transmission fit,
      ``d = (0.25/pi) radius scale / s(A)``, ``s(A) = 1.9 - A + 3.5 (A - 0.8)^2`` (``bssrdf_burley_fitting``).

    The surface albedo is the Subsurface Color (Base Color in 4.x), which Cycles puts into the closure weight.
    """
    albedo = _rgb("subsurface_color", subsurface_color, lo=0.0, hi=1.0)
    radius = _rgb("subsurface_radius", subsurface_radius, lo=0.0)
    scale = _scalar("subsurface_scale", subsurface_scale, positive=False)
    unit = _scalar("mm_per_unit", mm_per_unit)
    if cycles not in CYCLES_VERSIONS:
        raise ValueError(f"cycles={cycles!r} is not one of {CYCLES_VERSIONS}")
    # intern/cycles/kernel/closure/bssrdf.h: bssrdf_burley_compatible_mfp / bssrdf_setup_radius, 0.25 * M_1_PI_F
    d = radius * scale * unit / _FOUR_PI
    if cycles == "2.8":
        d = d / _s("diffuse_transmission", albedo)  # bssrdf.h (2.8x): bssrdf->radius = l / s, bssrdf_burley_fitting
    return albedo, d


def burley_to_blender(albedo, d_mm, *, subsurface_scale: float = 1.0, mm_per_unit: float = 1000.0,
                      cycles: str = "3.0+") -> dict[str, Any]:
    """Principled BSDF inputs (Cycles, Christensen–Burley) that render ``(albedo, d_mm)``; inverse of
    ``blender_to_burley``."""
    albedo, d = _material(albedo, d_mm)
    scale = _scalar("subsurface_scale", subsurface_scale)
    unit = _scalar("mm_per_unit", mm_per_unit)
    if cycles not in CYCLES_VERSIONS:
        raise ValueError(f"cycles={cycles!r} is not one of {CYCLES_VERSIONS}")
    radius = d * _FOUR_PI / (scale * unit)
    if cycles == "2.8":
        radius = radius * _s("diffuse_transmission", albedo)
    return {"Subsurface Color": albedo.tolist(), "Subsurface Radius": radius.tolist(), "Subsurface Scale": scale,
            "Subsurface Method": "Christensen-Burley", "mm_per_unit": unit, "cycles": cycles}


# EEVEE legacy: blender/blender source/blender/gpu/intern/gpu_material.c, compute_sss_kernel (2.80-3.x; the same code
# moved to eevee_subsurface/diffusion in later legacy versions): l = 0.25/pi * radius; A = 1.0f;
# s = 1.9 - A + 3.5 (A - 0.8)^2; d = l * 0.6 / s ("XXX 0.6f Out of nowhere to match cycles! Empirical!").
_EEVEE_EMPIRICAL = 0.6
EEVEE_DEFAULT_SAMPLES = 7  # scene.eevee.sss_samples default


def _eevee_factor() -> float:
    return _EEVEE_EMPIRICAL / (_FOUR_PI * float(_s("diffuse_transmission", 1.0)))


def eevee_to_burley(subsurface_color, subsurface_radius, *, subsurface_scale: float = 1.0,
                    mm_per_unit: float = 1000.0) -> tuple[np.ndarray, np.ndarray]:
    """(albedo, d_mm) of EEVEE legacy's kernel: ``d = 0.6 radius scale / (4 pi s(1))`` with the diffuse-transmission
    fit at the FIXED albedo A = 1 (``s(1) = 1.04``), whatever the Subsurface Color: LOSSY with respect to Cycles."""
    albedo = _rgb("subsurface_color", subsurface_color, lo=0.0, hi=1.0)
    radius = _rgb("subsurface_radius", subsurface_radius, lo=0.0)
    scale = _scalar("subsurface_scale", subsurface_scale, positive=False)
    unit = _scalar("mm_per_unit", mm_per_unit)
    return albedo, radius * scale * unit * _eevee_factor()


def burley_to_eevee(albedo, d_mm, *, subsurface_scale: float = 1.0, mm_per_unit: float = 1000.0,
                    samples: int = EEVEE_DEFAULT_SAMPLES) -> dict[str, Any]:
    """The node inputs that give EEVEE legacy's kernel the material's d (the same node renders another d in Cycles)."""
    albedo, d = _material(albedo, d_mm)
    scale = _scalar("subsurface_scale", subsurface_scale)
    unit = _scalar("mm_per_unit", mm_per_unit)
    radius = d / (scale * unit * _eevee_factor())
    return {"Subsurface Color": albedo.tolist(), "Subsurface Radius": radius.tolist(), "Subsurface Scale": scale,
            "mm_per_unit": unit, "Samples": int(samples)}


# ----------------------------------------------------------------------------------------------------------------
# Unity HDRP
# ----------------------------------------------------------------------------------------------------------------


def hdrp_to_burley(base_color, scattering_color, multiplier: float = 1.0, *, world_scale: float = 1.0,
                   mm_per_unit: float = 1000.0) -> tuple[np.ndarray, np.ndarray]:
    """(albedo, d_mm) rendered by an HDRP diffusion profile.

    Unity-Technologies/Graphics ``com.unity.render-pipelines.high-definition/Runtime/Material/DiffusionProfile/
    DiffusionProfileSettings.cs`` (``UpdateKernel``): ``sd = scatteringDistanceMultiplier * scatteringDistance``,
    ``shapeParam = 1 / sd`` in mm, i.e. Burley's d directly, no s(A). ``SubsurfaceScattering.compute``:
    ``mmPerUnit = MILLIMETERS_PER_METER * (metersPerUnit / distScale)`` with ``metersPerUnit`` = World Scale, so a
    profile millimetre covers ``1 / (1000 world_scale)`` scene units; with the scene unit truly ``mm_per_unit`` mm
    (Unity's metre: 1000), ``d = sd * mm_per_unit / (1000 world_scale)``. The surface albedo is the material's Base
    Color (the profile is normalised; HDRP multiplies by the albedo in the shader).
    """
    albedo = _rgb("base_color", base_color, lo=0.0, hi=1.0)
    color = _rgb("scattering_color", scattering_color, lo=0.0)
    mult = _scalar("multiplier", multiplier, positive=False)
    ws = _scalar("world_scale", world_scale)
    unit = _scalar("mm_per_unit", mm_per_unit)
    return albedo, color * mult * unit / (1000.0 * ws)


def burley_to_hdrp(albedo, d_mm, *, mm_per_unit: float = 1000.0) -> dict[str, Any]:
    """Diffusion profile for ``(albedo, d_mm)``: World Scale states the scene unit (``mm_per_unit / 1000`` m) and the
    scattering distance (mm) is split into an LDR colour and a multiplier as the editor does
    (``HDUtils.ConvertHDRColorToLDR``: ``scale = 191 / max``, ``color = scale c / 255``, ``multiplier = 255 / scale``).
    Scattering Color is linear here; the HDRP inspector shows it gamma-encoded."""
    albedo, d = _material(albedo, d_mm)
    unit = _scalar("mm_per_unit", mm_per_unit)
    peak = float(np.max(d))
    if peak > 0:
        factor = 191.0 / peak  # Unity-Technologies/Graphics HDUtils.cs, ConvertHDRColorToLDR (k_MaxByteForOverexposedColor)
        color, mult = np.minimum(191.0, factor * d) / 255.0, 255.0 / factor
    else:
        color, mult = d, 1.0
    return {"Base Color": albedo.tolist(), "Scattering Color": color.tolist(), "Multiplier": float(mult),
            "World Scale": unit / 1000.0, "mm_per_unit": unit,
            "Max Radius (mm)": float(np.max(burley_inverse_cdf_np(0.997, d)))}


def burley_inverse_cdf_np(u: float, d: np.ndarray) -> np.ndarray:
    """``burley_inverse_cdf`` in float64 on the host."""
    with jax.enable_x64(True):
        return np.asarray(burley_inverse_cdf(np.float64(u), np.asarray(d, np.float64)), np.float64)


def _burley_cdf_np(r, d) -> np.ndarray:
    with jax.enable_x64(True):
        return np.asarray(burley_cdf(np.asarray(r, np.float64), np.asarray(d, np.float64)), np.float64)


# ----------------------------------------------------------------------------------------------------------------
# Unreal Engine 5 (Burley subsurface profile)
# ----------------------------------------------------------------------------------------------------------------

# UE5 Engine/Source/Runtime/Engine/Private/Rendering/SubsurfaceProfile.cpp (CreateTexture):
#   DifffuseMeanFreePathInMm = GetDiffuseMeanFreePathFromMeanFreePath(SurfaceAlbedo, MeanFreePathColor *
#       MeanFreePathDistance) * CmToMm / Dmfp2MfpMagicNumber,   Dmfp2MfpMagicNumber = 0.6
# BurleyNormalizedSSS.cpp: GetDiffuseMeanFreePathFromMeanFreePath = MFP * s_searchlight_dmfp(A) / s_perpendicular(A)
# Engine/Shaders/Private/BurleyNormalizedSSSCommon.ush: GetScalingFactor3D = GetSearchLightDiffuseScalingFactor3D
#   (LIGHT_PERPENDICULAR_DIFFUSE_SURFACE 1); the profile is rR(r) with D = 1/S3D, R = r / DMFP: d = DMFP / s_dmfp(A).
# So d_kernel_mm = 10 MFP_cm / (0.6 s_perp(A)), s_perp = 1.85 - A + 7 |A - 0.8|^3 (the memo's searchlight fit).
_UE_DMFP2MFP = 0.6
_UE_CLAMP = 0.009  # SubsurfaceProfile.cpp: Bias = 0.009f; SurfaceAlbedo / MeanFreePathColor .GetClamped(Bias)
_UE_DMFP_MAX_MM = 500.0  # DEC_UNIT_TO_DIFFUSEMEANFREEPATH_IN_MM = 1 / (0.01 * 0.2)


def _ue_world_mm_per_kernel_mm(world_unit_scale: float, mm_per_unit: float) -> float:
    # Engine/Shaders/Private/SubsurfaceBurleyNormalized.ush, CalculateBurleyScale: UVOffset = BurleyScale * RadiusInMM,
    # BurleyScale = WorldUnitScale * SubsurfaceParams.x / Depth * (SUBSURFACE_KERNEL_SIZE / BURLEY_CM_2_MM), and
    # PostProcessSubsurface.cpp: SubsurfaceParams.x = P00 * r.SSS.Scale / SUBSURFACE_KERNEL_SIZE * 0.5 (scale 1).
    # A length l (scene units) at depth z spans 0.5 P00 l / z in UV, hence l = 0.1 * WorldUnitScale * r_kernel_mm.
    # (The bilateral depth term, DeltaDepth * BURLEY_CM_2_MM / WorldUnitScale, agrees for UE's centimetre units.)
    return 0.1 * world_unit_scale * mm_per_unit


def unreal_to_burley(surface_albedo, mean_free_path_color, mean_free_path_distance: float, *,
                     world_unit_scale: float = 0.1, mm_per_unit: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """(albedo, d_mm) of a UE5 Burley subsurface profile (Mean Free Path Distance in cm; UE's unit: 10 mm).

    ``d = 10 MFP_cm / (0.6 s_perp(A))`` profile mm (see the constants above for the source lines), times the world
    scale ``0.1 world_unit_scale mm_per_unit`` from ``CalculateBurleyScale``. The world-scale step is derived from
    the shader code, not checked against a UE render. UE clamps Surface Albedo and Mean Free Path Color to >= 0.009.
    """
    albedo = np.maximum(_rgb("surface_albedo", surface_albedo, lo=0.0, hi=1.0), _UE_CLAMP)
    color = np.maximum(_rgb("mean_free_path_color", mean_free_path_color, lo=0.0), _UE_CLAMP)
    dist = _scalar("mean_free_path_distance", mean_free_path_distance)
    wus = _scalar("world_unit_scale", world_unit_scale)
    unit = _scalar("mm_per_unit", mm_per_unit)
    mfp_mm = 10.0 * color * dist
    dmfp = np.minimum(mfp_mm * _s("diffuse_mfp", albedo) / _s("searchlight", albedo) / _UE_DMFP2MFP, _UE_DMFP_MAX_MM)
    d_kernel = dmfp / _s("diffuse_mfp", albedo)
    return albedo, d_kernel * _ue_world_mm_per_kernel_mm(wus, unit)


def burley_to_unreal(albedo, d_mm, *, world_unit_scale: float = 0.1, mm_per_unit: float = 10.0) -> dict[str, Any]:
    """UE5 subsurface profile for ``(albedo, d_mm)``: Mean Free Path Distance is the largest channel's MFP (cm) and
    the colour the ratio, as ``UpgradeDiffuseMeanFreePathToMeanFreePath`` in SubsurfaceProfile.cpp splits them."""
    albedo, d = _material(albedo, d_mm)
    wus = _scalar("world_unit_scale", world_unit_scale)
    unit = _scalar("mm_per_unit", mm_per_unit)
    d_kernel = d / _ue_world_mm_per_kernel_mm(wus, unit)
    mfp_cm = d_kernel * _UE_DMFP2MFP * _s("searchlight", albedo) / 10.0
    dist = float(np.max(mfp_cm))
    color = mfp_cm / dist if dist > 0 else np.zeros(3)
    warnings = []
    if np.any(albedo < _UE_CLAMP) or np.any((color < _UE_CLAMP) & (d > 0)):
        warnings.append("a component of Surface Albedo or Mean Free Path Color is below UE's clamp 0.009: UE renders "
                        "it larger")
    if np.any(d_kernel * _s("diffuse_mfp", albedo) > _UE_DMFP_MAX_MM):
        warnings.append("the diffuse mean free path exceeds UE's 500 mm encoding range and is clamped")
    out = {"Surface Albedo": albedo.tolist(), "Mean Free Path Color": color.tolist(),
           "Mean Free Path Distance": dist, "World Unit Scale": wus, "mm_per_unit": unit}
    if warnings:
        out["warnings"] = warnings
    return out


# ----------------------------------------------------------------------------------------------------------------
# Jimenez et al. separable SSS (iryoku/separable-sss)
# ----------------------------------------------------------------------------------------------------------------

# iryoku/separable-sss Demo/Code/SeparableSSS.cpp, SeparableSSS::profile: the red channel of d'Eon et al.'s skin fit
# for every channel, without the narrowest Gaussian (0.233 at v = 0.0064, "accounted by the strength parameter").
_JIMENEZ_PROFILE = ((0.100, 0.0484), (0.118, 0.187), (0.113, 0.567), (0.358, 1.99), (0.078, 7.41))
JIMENEZ_DEFAULT_SAMPLES = 17  # SeparableSSS.h, SSSS_QUALITY 1


def _jimenez_profile(r: np.ndarray, falloff: np.ndarray) -> np.ndarray:
    """SeparableSSS::profile / gaussian: ``sum w exp(-rr^2 / 2v) / (2 * 3.14 * v)``, ``rr = r / (0.001 + falloff)``."""
    rr = r[:, None] / (0.001 + falloff[None, :])
    return sum(w * np.exp(-(rr * rr) / (2.0 * v)) / (2.0 * 3.14 * v) for w, v in _JIMENEZ_PROFILE)


def jimenez_kernel(strength, falloff, *, n_samples: int = JIMENEZ_DEFAULT_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """``SeparableSSS::calculateKernel`` (iryoku/separable-sss Demo/Code/SeparableSSS.cpp) in float64.

    Returns ``offsets (n,)`` in kernel units (``kernel[i].w``, in [-RANGE, RANGE], RANGE = 3 above 20 samples else 2)
    and ``weights (n, 3)``, centre tap first as the shader expects. Weights: ``area * profile(offset)``, normalised
    per channel, then ``lerp(1, k0, strength)`` for the centre and ``k_i * strength`` for the others.
    """
    strength = _rgb("strength", strength, lo=0.0, hi=1.0)
    falloff = _rgb("falloff", falloff, lo=0.0, hi=1.0)
    n = int(n_samples)
    if n < 3 or n % 2 == 0:
        raise ValueError(f"n_samples must be an odd number >= 3, got {n_samples!r}")
    rng = 3.0 if n > 20 else 2.0
    exponent = 2.0
    step = 2.0 * rng / (n - 1)
    o = -rng + np.arange(n) * step
    offsets = rng * np.where(o < 0, -1.0, 1.0) * np.abs(o**exponent) / rng**exponent
    left = np.r_[0.0, np.abs(np.diff(offsets))]
    right = np.r_[np.abs(np.diff(offsets)), 0.0]
    area = (left + right) / 2.0
    weights = area[:, None] * _jimenez_profile(offsets, falloff)
    order = np.r_[n // 2, np.delete(np.arange(n), n // 2)]  # "we want the offset 0.0 to come first"
    offsets, weights = offsets[order], weights[order]
    weights = weights / np.sum(weights, axis=0)
    weights[0] = (1.0 - strength) + strength * weights[0]
    weights[1:] = weights[1:] * strength
    return offsets, weights


def _jimenez_world_mm(sss_width: float, mm_per_unit: float) -> float:
    # SeparableSSS.h, SSSSBlurPS: finalStep = sssWidth * (1/tan(fovy/2)) / depth * dir / 3 in texture coordinates;
    # a length l at depth z spans 0.5 l / (z tan(fovy/2)) of them (vertical axis), so a kernel unit is 2/3 sssWidth.
    # (The horizontal pass uses the same scale, so on a non-square viewport it is wider by the aspect ratio.)
    return 2.0 / 3.0 * sss_width * mm_per_unit


# --- 1D marginals: every engine's kernel as bin masses of the 1D marginal (what one separable pass applies) --------


def _bins(d: np.ndarray) -> np.ndarray:
    """Per-channel bin edges (3, 162): width d/4 over [-20.125 d, 20.125 d], one bin centred on 0."""
    return d[:, None] * (np.arange(-80, 82) - 0.5)[None, :] / 4.0


def _masses_from_cdf(cdf_at_edges: np.ndarray) -> np.ndarray:
    """Bin masses plus the two tails (mass below the first and above the last edge)."""
    return np.concatenate([cdf_at_edges[:, :1], np.diff(cdf_at_edges, axis=1), 1.0 - cdf_at_edges[:, -1:]], axis=1)


def _radial_marginal_cdf(x: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """1D marginal CDF of a radial distribution given by equal-mass radius quantiles ``radii (Q,)``:
    ``P(X <= x) = 1/2 + sign(x)/2 * mean_q P(|r_q cos theta| <= |x|)`` (the same estimator as ``marginal_cdf``)."""
    ax = np.abs(x)[..., None]
    r = radii[None, :]
    inside = np.where(r > ax, (2.0 / math.pi) * np.arcsin(np.clip(ax / np.where(r > 0, r, 1.0), 0.0, 1.0)), 1.0)
    return 0.5 + 0.5 * np.sign(x) * np.mean(inside, axis=-1)


_QUANTILES = (np.arange(8192) + 0.5) / 8192


def _burley_marginal_masses(d: np.ndarray, edges: np.ndarray, u_max=None) -> np.ndarray:
    """Bin masses of the 1D marginal of the normalised Burley profile per channel, optionally truncated at the radius
    where its CDF reaches ``u_max`` (3,) and renormalised (what Cycles and HDRP render)."""
    u_max = np.ones(3) if u_max is None else np.asarray(u_max, np.float64)
    cdfs = []
    for c in range(3):
        if d[c] <= 0:
            cdfs.append(np.where(edges[c] >= 0, 1.0, 0.0))
            continue
        radii = burley_inverse_cdf_np_vec(_QUANTILES * u_max[c], d[c])
        cdfs.append(_radial_marginal_cdf(edges[c], radii))
    return _masses_from_cdf(np.stack(cdfs))


def burley_inverse_cdf_np_vec(u: np.ndarray, d: float) -> np.ndarray:
    with jax.enable_x64(True):
        return np.asarray(burley_inverse_cdf(np.asarray(u, np.float64), np.float64(d)), np.float64)


def _piecewise_masses(lo: np.ndarray, hi: np.ndarray, weights: np.ndarray, edges: np.ndarray,
                      dirac: np.ndarray | None = None) -> np.ndarray:
    """Bin masses of a density that spreads tap ``i``'s weight (n, 3) uniformly over ``[lo_i, hi_i]`` (mm), plus an
    optional Dirac (3,) at 0: the model behind calculateKernel's ``area * profile`` and EEVEE's footprint integrals."""
    width = np.maximum(hi - lo, 1e-300)
    cdfs = []
    for c in range(3):
        x = edges[c][:, None]
        frac = np.clip((x - lo[None, :]) / width[None, :], 0.0, 1.0)
        cdf = frac @ weights[:, c]
        if dirac is not None:
            cdf = cdf + dirac[c] * (edges[c] >= 0)
        cdfs.append(cdf)
    return _masses_from_cdf(np.stack(cdfs))


def _jimenez_masses(strength, falloff, sss_width, mm_per_unit, n_samples, edges) -> np.ndarray:
    offsets, weights = jimenez_kernel(strength, falloff, n_samples=n_samples)
    order = np.argsort(offsets)
    w_sorted = offsets[order]
    k = _jimenez_world_mm(sss_width, mm_per_unit)
    mids = (w_sorted[1:] + w_sorted[:-1]) / 2.0
    lo = np.r_[w_sorted[0], mids] * k
    hi = np.r_[mids, w_sorted[-1]] * k
    strength = _rgb("strength", strength)
    spread = weights[order].copy()
    centre = int(np.where(order == 0)[0][0])
    spread[centre] -= 1.0 - strength  # the lerp(1, k0, strength) part is a Dirac: the unblurred pixel
    return _piecewise_masses(lo, hi, spread, edges, dirac=1.0 - strength)


def _eevee_masses(d_eevee: np.ndarray, samples: int, edges: np.ndarray) -> np.ndarray:
    """EEVEE legacy's separable kernel (gpu_material.c compute_sss_kernel) as footprint masses: offsets
    ``sign(o) o^2``, o uniform in [-1, 1], times ``max_radius = 16 max(d)``; weight i is the 32-point midpoint integral
    of ``burley_profile(|x|, d) = (exp(-x/d) + exp(-x/(3d))) / (4d)`` (the RADIAL pdf 2 pi r R(r) used as a 1D
    kernel) over the tap's footprint, normalised per channel."""
    n = int(samples)
    o = np.arange(n) * (2.0 / (n - 1)) - 1.0
    k = np.where(o < 0, -1.0, 1.0) * np.abs(o**2.0)
    max_radius = 16.0 * float(np.max(d_eevee))
    x0 = np.r_[k[0] - abs(k[0] - k[1]) / 2.0, (k[:-1] + k[1:]) / 2.0] * max_radius
    x1 = np.r_[(k[:-1] + k[1:]) / 2.0, k[-1] + abs(k[-2] - k[-1]) / 2.0] * max_radius
    t = (np.arange(32) + 0.5) / 32
    xs = x0[:, None] + (x1 - x0)[:, None] * t[None, :]  # (n, 32)
    weights = np.empty((n, 3))
    for c in range(3):
        dc = max(float(d_eevee[c]), 1e-15)
        ax = np.abs(xs)
        prof = (np.exp(-ax / dc) + np.exp(-ax / (3 * dc))) / (4 * dc) / 0.9963790093708328
        weights[:, c] = np.sum(prof, axis=1) * (x1 - x0) / 32
    weights = weights / np.sum(weights, axis=0)
    return _piecewise_masses(x0, x1, weights, edges)


def _relative_l2(masses: np.ndarray, reference: np.ndarray) -> np.ndarray:
    return np.linalg.norm(masses - reference, axis=1) / np.linalg.norm(reference, axis=1)


def burley_to_jimenez(albedo, d_mm, *, mm_per_unit: float = 1000.0,
                      n_samples: int = JIMENEZ_DEFAULT_SAMPLES) -> dict[str, Any]:
    """Fitted separable-SSS parameters (sssWidth in scene units, strength (3,), falloff (3,)) for ``(albedo, d_mm)``.

    Objective (documented, also what ``engine_profile_error`` reports): per channel c, the 1D marginal of the
    Burley profile (what one separable pass must apply) and the kernel that calculateKernel builds are both turned
    into masses of 161 bins of width d_c/4 centred on 0 plus the two tails beyond +-20.125 d_c; each Jimenez tap's
    weight is spread uniformly over its footprint (the ``area`` calculateKernel integrates over), the ``1 - strength``
    part of the centre tap is a Dirac. Residuals ``(m_jimenez - m_burley) / ||m_burley||`` of the three channels are
    minimised together by ``scipy.optimize.least_squares`` (trust region reflective) over ``log(sssWidth)``,
    falloff in [0, 1] and strength in [0, 1], from four starting widths; the best is kept. sssWidth is shared by the
    channels: this is the lossy part.
    """
    from scipy.optimize import least_squares

    albedo, d = _material(albedo, d_mm)
    unit = _scalar("mm_per_unit", mm_per_unit)
    if not np.all(d > 0):
        raise ValueError(f"burley_to_jimenez needs d_mm > 0 in every channel, got {d.tolist()}")
    edges = _bins(d)
    ref = _burley_marginal_masses(d, edges)
    norm = np.linalg.norm(ref, axis=1, keepdims=True)

    def residuals(p):
        width = math.exp(p[0])
        m = _jimenez_masses(p[4:7], p[1:4], width, unit, n_samples, edges)
        return ((m - ref) / norm).ravel()

    best = None
    dmax = float(np.max(d))
    for scale in (1.0, 2.0, 4.0, 8.0):
        # a kernel unit covers 2/3 sssWidth; start with the widest channel's falloff 1 reaching ~scale d
        width0 = scale * dmax / (_jimenez_world_mm(1.0, unit))
        x0 = np.r_[math.log(width0), np.clip(d / dmax, 0.05, 1.0), np.full(3, 0.6)]
        lo = np.r_[-np.inf, np.zeros(6)]
        hi = np.r_[np.inf, np.ones(6)]
        sol = least_squares(residuals, x0, bounds=(lo, hi), method="trf", x_scale="jac", max_nfev=400)
        if best is None or sol.cost < best.cost:
            best = sol
    p = best.x
    err = _relative_l2(_jimenez_masses(p[4:7], p[1:4], math.exp(p[0]), unit, n_samples, edges), ref)
    return {"sssWidth": math.exp(p[0]), "strength": p[4:7].tolist(), "falloff": p[1:4].tolist(),
            "nSamples": int(n_samples), "mm_per_unit": unit, "albedo": albedo.tolist(),
            "fit": {"solver": "scipy.optimize.least_squares(trf)", "status": int(best.status),
                    "evaluations": int(best.nfev), "error_relative_l2": err.tolist(),
                    "metric": "relative L2 of 1D-marginal bin masses (width d/4, +-20 d, tails), per channel"}}


def jimenez_to_burley(albedo, sss_width: float, strength, falloff, *, mm_per_unit: float = 1000.0,
                      n_samples: int = JIMENEZ_DEFAULT_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """The Burley d per channel closest to a separable-SSS kernel (same objective as ``burley_to_jimenez``, one scalar
    per channel, bins of width d/4 of the candidate d); separable SSS has no albedo of its own: pass the texture's."""
    from scipy.optimize import minimize_scalar

    albedo = _rgb("albedo", albedo, lo=0.0, hi=1.0)
    width = _scalar("sss_width", sss_width)
    unit = _scalar("mm_per_unit", mm_per_unit)
    strength = _rgb("strength", strength, lo=0.0, hi=1.0)
    falloff = _rgb("falloff", falloff, lo=0.0, hi=1.0)
    k = _jimenez_world_mm(width, unit)
    d = np.empty(3)
    for c in range(3):
        def objective(logd, c=c):
            dc = np.full(3, math.exp(logd))
            edges = _bins(dc)
            ref = _burley_marginal_masses(dc, edges)[c]
            m = _jimenez_masses(strength, falloff, width, unit, n_samples, edges)[c]
            return float(np.sum((m - ref) ** 2) / np.sum(ref**2))

        scale = k * (0.001 + falloff[c])
        sol = minimize_scalar(objective, bounds=(math.log(scale * 1e-3), math.log(scale * 10.0)), method="bounded",
                              options={"xatol": 1e-6})
        d[c] = math.exp(sol.x)
    return albedo, d


# ----------------------------------------------------------------------------------------------------------------
# Generic entry points
# ----------------------------------------------------------------------------------------------------------------


def _check_engine(name: str) -> None:
    if name not in ENGINES:
        raise ValueError(f"unknown engine {name!r}; valid engines: {', '.join(ENGINES)}")


def to_engine(engine: str, albedo, d_mm, **options) -> dict[str, Any]:
    """The engine's parameters (UI names) for the sss_jax material ``(albedo, d_mm)``."""
    _check_engine(engine)
    if engine == "sss_jax":
        a, d = _material(albedo, d_mm)
        return {"albedo": a.tolist(), "d_mm": d.tolist()}
    fn = {"blender": burley_to_blender, "eevee": burley_to_eevee, "hdrp": burley_to_hdrp,
          "unreal": burley_to_unreal, "jimenez": burley_to_jimenez}[engine]
    return fn(albedo, d_mm, **options)


def from_engine(engine: str, params: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(albedo, d_mm) from an engine's parameters, given by the UI names ``to_engine`` writes."""
    _check_engine(engine)
    p = dict(params)

    def take(key, default=KeyError):
        if key in p:
            return p[key]
        if default is KeyError:
            raise ValueError(f"{engine} parameters need {key!r}")
        return default

    if engine == "sss_jax":
        return _material(take("albedo"), take("d_mm"))
    if engine == "blender":
        return blender_to_burley(take("Subsurface Color"), take("Subsurface Radius"),
                                 subsurface_scale=take("Subsurface Scale", 1.0), mm_per_unit=take("mm_per_unit", 1000.0),
                                 cycles=take("cycles", "3.0+"))
    if engine == "eevee":
        return eevee_to_burley(take("Subsurface Color"), take("Subsurface Radius"),
                               subsurface_scale=take("Subsurface Scale", 1.0), mm_per_unit=take("mm_per_unit", 1000.0))
    if engine == "hdrp":
        return hdrp_to_burley(take("Base Color"), take("Scattering Color"), take("Multiplier", 1.0),
                              world_scale=take("World Scale", 1.0), mm_per_unit=take("mm_per_unit", 1000.0))
    if engine == "unreal":
        return unreal_to_burley(take("Surface Albedo"), take("Mean Free Path Color"), take("Mean Free Path Distance"),
                                world_unit_scale=take("World Unit Scale", 0.1), mm_per_unit=take("mm_per_unit", 10.0))
    return jimenez_to_burley(take("albedo", (1.0, 1.0, 1.0)), take("sssWidth"), take("strength"), take("falloff"),
                             mm_per_unit=take("mm_per_unit", 1000.0), n_samples=take("nSamples", JIMENEZ_DEFAULT_SAMPLES))


def convert(source: str, target: str, params: dict[str, Any], **target_options) -> dict[str, Any]:
    """Convert a material from ``source``'s parameters to ``target``'s: ``{"from", "to", "albedo", "burley":
    {"d_mm"}, target: {...}, "lossy": reason or None}`` (JSON-serialisable)."""
    _check_engine(source)
    _check_engine(target)
    albedo, d = from_engine(source, params)
    out = {"from": source, "to": target, "albedo": albedo.tolist(), "burley": {"d_mm": d.tolist()},
           target: to_engine(target, albedo, d, **target_options)}
    reasons = [f"{e}: {LOSSY[e]}" for e in dict.fromkeys((source, target)) if LOSSY[e]]
    out["lossy"] = "; ".join(reasons) if reasons else None
    return out


def engine_blocks(albedo, d_mm, *, mm_per_unit: float | None = None) -> dict[str, dict[str, Any]]:
    """One block per engine for a preset (``fits/<material>.json``): that engine's parameters for the material, with
    each engine's default scene unit (Blender/EEVEE/Jimenez 1 m, HDRP 1 m, UE 1 cm) unless ``mm_per_unit`` is given."""
    albedo, d = _material(albedo, d_mm)
    blocks = {}
    for engine, default_unit in (("blender", 1000.0), ("eevee", 1000.0), ("hdrp", 1000.0), ("unreal", 10.0),
                                 ("jimenez", 1000.0)):
        unit = default_unit if mm_per_unit is None else mm_per_unit
        if engine == "jimenez" and not np.all(d > 0):
            blocks[engine] = {"error": "separable SSS needs d_mm > 0 in every channel"}
            continue
        blocks[engine] = to_engine(engine, albedo, d, mm_per_unit=unit)
        if LOSSY[engine]:
            blocks[engine]["lossy"] = LOSSY[engine]
    return blocks


def engine_marginals(albedo, d_mm, *, eevee_samples: int = EEVEE_DEFAULT_SAMPLES,
                     jimenez_samples: int = JIMENEZ_DEFAULT_SAMPLES) -> dict[str, Any]:
    """What each engine renders for the material, as 1D-marginal bin masses (3, 163) on the reference bins.

    ``edges`` (3, 162) in mm; ``reference``: the untruncated Burley marginal; ``cycles``: Burley truncated at 16 d and
    renormalised (``BURLEY_TRUNCATE``, ``bssrdf_burley_pdf``); ``hdrp``: truncated at the filter radius (CDF 0.997 of
    the widest channel, ``UpdateKernel``) and renormalised by the shader's weight sum; ``unreal``: the Burley profile
    with UE's clamps; ``eevee``: ``compute_sss_kernel`` with its d; ``jimenez``: calculateKernel with the fitted
    parameters. Masses are normalised profiles; each engine's albedo factor is in ``albedo``.
    """
    albedo, d = _material(albedo, d_mm)
    if not np.all(d > 0):
        raise ValueError(f"engine_marginals needs d_mm > 0 in every channel, got {d.tolist()}")
    edges = _bins(d)
    out: dict[str, Any] = {"edges": edges, "reference": _burley_marginal_masses(d, edges)}
    out["cycles"] = _burley_marginal_masses(d, edges, u_max=_burley_cdf_np(16.0 * d, d))
    r_filter = float(np.max(burley_inverse_cdf_np(0.997, d)))
    out["hdrp"] = _burley_marginal_masses(d, edges, u_max=_burley_cdf_np(np.full(3, r_filter), d))
    ue = burley_to_unreal(albedo, d)
    ue_albedo, ue_d = unreal_to_burley(ue["Surface Albedo"], ue["Mean Free Path Color"], ue["Mean Free Path Distance"],
                                       world_unit_scale=ue["World Unit Scale"], mm_per_unit=ue["mm_per_unit"])
    out["unreal"] = _burley_marginal_masses(ue_d, edges)
    out["eevee"] = _eevee_masses(d, eevee_samples, edges)
    fit = burley_to_jimenez(albedo, d, n_samples=jimenez_samples)
    out["jimenez"] = _jimenez_masses(fit["strength"], fit["falloff"], fit["sssWidth"], fit["mm_per_unit"],
                                     jimenez_samples, edges)
    out["albedo"] = {"reference": albedo, "cycles": albedo, "hdrp": albedo, "unreal": ue_albedo, "eevee": albedo,
                     "jimenez": albedo}
    out["jimenez_parameters"] = fit
    return out


def engine_profile_error(albedo, d_mm, **options) -> dict[str, dict[str, list[float]]]:
    """Per engine, how far its rendered kernel is from the Burley reference of the material, per channel.

    ``error_relative_l2``: ``||m_engine - m_ref|| / ||m_ref||`` over the 1D-marginal bin masses of
    ``engine_marginals`` (161 bins of width d/4 centred on 0 plus both tails); the 1D marginal is what one pass of a
    separable engine applies and what a radial engine's kernel projects to. ``energy_lost``: ``1 - A_engine sum(m_engine)
    / (A sum(m_ref))``, the fraction of the material's diffuse reflectance the engine does not return (renormalising
    engines lose none; UE only through its albedo clamp). ``cycles`` is Blender's Christensen–Burley (either
    version: the converted radius gives the same d).
    """
    marg = engine_marginals(albedo, d_mm, **options)
    return engine_errors_against(marg, marg["reference"], marg["albedo"]["reference"])


def engine_errors_against(marg: dict[str, Any], ref: np.ndarray, ref_albedo) -> dict[str, dict[str, list[float]]]:
    """Each engine's marginal masses of ``engine_marginals`` against reference masses ``ref (3, 163)`` on the same
    bins (Burley's, or a Monte Carlo profile's) with that reference's albedo (3,): relative L2 and energy lost."""
    a_ref = np.asarray(ref_albedo, np.float64)
    out = {}
    for engine in ("cycles", "eevee", "hdrp", "unreal", "jimenez"):
        m = marg[engine]
        a = np.asarray(marg["albedo"][engine])
        total = a * np.sum(m, axis=1)
        lost = np.where(a_ref > 0, 1.0 - total / np.where(a_ref > 0, a_ref * np.sum(ref, axis=1), 1.0), 0.0)
        out[engine] = {"error_relative_l2": _relative_l2(m, ref).tolist(), "energy_lost": lost.tolist()}
    return out
