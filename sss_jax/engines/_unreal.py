"""Unreal Engine 5: a Burley subsurface profile (Surface Albedo, Mean Free Path Color x Distance, World Unit Scale)
and the material's Opacity, which scales the scattering distance of a Subsurface Profile material.

UE5 ``Engine/Source/Runtime/Engine/Private/Rendering/SubsurfaceProfile.cpp`` (``CreateTexture``):
``DifffuseMeanFreePathInMm = GetDiffuseMeanFreePathFromMeanFreePath(SurfaceAlbedo, MeanFreePathColor *
MeanFreePathDistance) * CmToMm / Dmfp2MfpMagicNumber`` (0.6); ``BurleyNormalizedSSS.cpp``:
``GetDiffuseMeanFreePathFromMeanFreePath = MFP * s_searchlight_dmfp(A) / s_perpendicular(A)``;
``Engine/Shaders/Private/BurleyNormalizedSSSCommon.ush``: ``GetScalingFactor3D`` (the searchlight-dmfp fit), profile
``D = 1/S3D``, ``R = r / DMFP``: ``d = DMFP / s_dmfp(A)``. So ``d_kernel_mm = 10 MFP_cm / (0.6 s_perp(A))``.
The world scale (``_world_mm_per_kernel_mm``) is UNVERIFIED: see ``Unreal.unverified``.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ._base import ALBEDO_HELP, MM_PER_UNIT, AbstractEngine, Flag
from ._common import burley_marginal_masses, material, rgb, s_fit, scalar

_UE_DMFP2MFP = 0.6
_UE_CLAMP = 0.009  # SubsurfaceProfile.cpp: Bias = 0.009f; SurfaceAlbedo / MeanFreePathColor .GetClamped(Bias)
_UE_DMFP_MAX_MM = 500.0  # DEC_UNIT_TO_DIFFUSEMEANFREEPATH_IN_MM = 1 / (0.01 * 0.2)


def _world_mm_per_kernel_mm(world_unit_scale: float, mm_per_unit: float) -> float:
    # Engine/Shaders/Private/SubsurfaceBurleyNormalized.ush, CalculateBurleyScale: UVOffset = BurleyScale * RadiusInMM,
    # BurleyScale = WorldUnitScale * SubsurfaceParams.x / Depth * (SUBSURFACE_KERNEL_SIZE / BURLEY_CM_2_MM), and
    # PostProcessSubsurface.cpp: SubsurfaceParams.x = P00 * r.SSS.Scale / SUBSURFACE_KERNEL_SIZE * 0.5 (scale 1).
    # A length l (scene units) at depth z spans 0.5 P00 l / z in UV, hence l = 0.1 * WorldUnitScale * r_kernel_mm.
    # Other mirrors scale by 10 x WorldUnitScale (GetBurleyParameters) and shader versions differ by 10/3: unverified.
    return 0.1 * world_unit_scale * mm_per_unit


class Unreal(AbstractEngine):
    """UE5 Burley: ``d = 10 MFP_cm / (0.6 s_perp(A))`` profile mm, times Opacity and the world scale."""

    name: ClassVar[str] = "unreal"
    title: ClassVar[str] = "Unreal Engine 5 (Burley subsurface profile)"
    default_mm_per_unit: ClassVar[float] = 10.0
    kernel: ClassVar[str | None] = "unreal"
    lossy: ClassVar[str | None] = (
        "exact unless a component of Surface Albedo or Mean Free Path Color is below UE's clamp of 0.009 or the "
        "diffuse mean free path exceeds its 500 mm encoding range")
    unverified: ClassVar[str | None] = (
        "World Unit Scale: the profile-mm to scene-unit factor used here, 0.1 x World Unit Scale (CalculateBurleyScale "
        "in SubsurfaceBurleyNormalized.ush with PostProcessSubsurface.cpp's SubsurfaceParams), is not resolved "
        "against UE's own source per version: public mirrors disagree by 10x (10 x World Unit Scale in "
        "GetBurleyParameters) and shader versions by another 10/3, and it was not checked against a UE render; "
        "Opacity scaling d is likewise not read from UE's source. Check the scale in the editor before relying on it")
    source: ClassVar[str] = ("UE5 Engine/Source/Runtime/Engine/Private/Rendering/SubsurfaceProfile.cpp, "
                             "BurleyNormalizedSSS.cpp, Engine/Shaders/Private/BurleyNormalizedSSSCommon.ush, "
                             "SubsurfaceBurleyNormalized.ush (CalculateBurleyScale), PostProcessSubsurface.cpp; read "
                             "from public mirrors (unicorn2022/UE5.8.0, izzy2lost/UnrealEngineUWP, "
                             "chenyong2github/UnrealEngine)")
    flags: ClassVar[tuple[Flag, ...]] = (
        Flag("--albedo", ALBEDO_HELP, key="Surface Albedo", required=True),
        Flag("--mfp-color", "unreal: Mean Free Path Color", key="Mean Free Path Color", required=True),
        Flag("--mfp-distance", "unreal: Mean Free Path Distance, cm", key="Mean Free Path Distance", kind="float",
             required=True),
        Flag("--world-unit-scale", "unreal: World Unit Scale (default 0.1)", key="World Unit Scale",
             option="world_unit_scale", kind="float"),
        Flag("--opacity", "unreal: the material's Opacity, scales d (default 1)", key="Opacity", option="opacity",
             kind="float"),
        MM_PER_UNIT,
    )

    def to_engine(self, albedo, d_mm, *, world_unit_scale: float = 0.1, mm_per_unit: float = 10.0,
                  opacity: float = 1.0) -> dict[str, Any]:
        """UE5 subsurface profile for ``(albedo, d_mm)`` on a material of ``opacity``: Mean Free Path Distance is
        the largest channel's MFP (cm) and the colour the ratio, as ``UpgradeDiffuseMeanFreePathToMeanFreePath`` in
        SubsurfaceProfile.cpp splits them. The output carries ``unverified`` (the world scale)."""
        albedo, d = material(albedo, d_mm)
        wus = scalar("world_unit_scale", world_unit_scale)
        unit = scalar("mm_per_unit", mm_per_unit)
        op = scalar("opacity", opacity, hi=1.0)
        d_kernel = d / (op * _world_mm_per_kernel_mm(wus, unit))
        mfp_cm = d_kernel * _UE_DMFP2MFP * s_fit("searchlight", albedo) / 10.0
        dist = float(np.max(mfp_cm))
        color = mfp_cm / dist if dist > 0 else np.zeros(3)
        warnings = []
        if np.any(albedo < _UE_CLAMP) or np.any((color < _UE_CLAMP) & (d > 0)):
            warnings.append("a component of Surface Albedo or Mean Free Path Color is below UE's clamp 0.009: UE "
                            "renders it larger")
        if dist > 0 and np.any(d == 0):
            channels = ", ".join("RGB"[c] for c in np.flatnonzero(d == 0))
            warnings.append(f"channel {channels} has d = 0 (no scattering), written as Mean Free Path Color 0: UE "
                            f"clamps it to {_UE_CLAMP} and scatters it over {_UE_CLAMP} of the Mean Free Path Distance "
                            f"({_UE_CLAMP * dist:.3g} cm)")
        if np.any(d_kernel * s_fit("diffuse_mfp", albedo) > _UE_DMFP_MAX_MM):
            warnings.append("the diffuse mean free path exceeds UE's 500 mm encoding range and is clamped")
        out = {"Surface Albedo": albedo.tolist(), "Mean Free Path Color": color.tolist(),
               "Mean Free Path Distance": dist, "World Unit Scale": wus, "Opacity": op, "mm_per_unit": unit,
               "unverified": self.unverified}
        if warnings:
            out["warnings"] = warnings
        return out

    def from_engine(self, params: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        for key in ("Surface Albedo", "Mean Free Path Color", "Mean Free Path Distance"):
            if key not in params:
                raise ValueError(f"unreal parameters need {key!r}")
        albedo = np.maximum(rgb("surface_albedo", params["Surface Albedo"], lo=0.0, hi=1.0), _UE_CLAMP)
        color = np.maximum(rgb("mean_free_path_color", params["Mean Free Path Color"], lo=0.0), _UE_CLAMP)
        dist = scalar("mean_free_path_distance", params["Mean Free Path Distance"])
        wus = scalar("world_unit_scale", params.get("World Unit Scale", 0.1))
        unit = scalar("mm_per_unit", params.get("mm_per_unit", 10.0))
        op = scalar("opacity", params.get("Opacity", 1.0), positive=False, lo=0.0, hi=1.0)
        mfp_mm = 10.0 * color * dist
        dmfp = np.minimum(mfp_mm * s_fit("diffuse_mfp", albedo) / s_fit("searchlight", albedo) / _UE_DMFP2MFP,
                          _UE_DMFP_MAX_MM)
        d_kernel = dmfp / s_fit("diffuse_mfp", albedo)
        return albedo, d_kernel * op * _world_mm_per_kernel_mm(wus, unit)

    def marginal(self, albedo, d_mm, edges, params=None):
        """The Burley profile with UE's clamps: the material through UE's parameters and back."""
        p = self.to_engine(albedo, d_mm) if params is None else params
        ue_albedo, ue_d = self.from_engine(p)
        return burley_marginal_masses(ue_d, edges), ue_albedo
