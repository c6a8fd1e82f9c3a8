"""Back-lighting through thin parts: the simple translucency approximation (STA) and the profile's and slab's
physically based transmission. These ADD light (they do not conserve energy)."""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import check_host_range, checked, clamp, is_bool
from .._custom_types import ParamLike
from .._materials import BurleyMaterial, DirectionalLight, STAParams
from .._profiles import burley_ccdf
from .._scene import Buffers, Camera, normals_from_depth, view_directions
from .._slab import MediumMaterial, slab_diffuse_transmittance, slab_exit_lookup, slab_exit_table, slab_optical
from ._common import _is_concrete, _prepare, _work_dtype, as_output, check_one_image


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
    # every parameter checked where it is traced too (a host value was checked when STAParams was made): under jit
    # a negative scale gave negative light, a NaN ambient a NaN image
    distortion = checked(params.distortion.astype(dtype), "STA distortion")
    lt = l.reshape(1, 1, 3) + distortion * normal
    # the norm through a square kept off 0: where L + d N vanishes (d = 1, the light straight behind a surface that
    # faces it) the forward pass gives 0, and |x|'s derivative at 0 would be NaN in every parameter
    sq = jnp.sum(lt * lt, axis=-1, keepdims=True)
    ok = sq > 1e-24
    lt = jnp.where(ok, lt / jnp.sqrt(jnp.where(ok, sq, 1.0)), 0.0)
    cos_back = jnp.clip(jnp.sum(view * -lt, axis=-1), 0.0, 1.0)
    power = checked(params.power.astype(dtype), "STA power")
    scale = checked(params.scale.astype(dtype), "STA scale")
    ambient = checked(params.ambient.astype(dtype), "STA ambient")
    t_dir = scale.reshape(1, 1, 3) * _safe_pow(cos_back, power)[..., None]
    # thickness_mm = inf is paper-thin (t = 1 at any finite thickness): allowed, as STAParams allows it
    scale_mm = checked(params.thickness_mm.astype(dtype), "STA thickness_mm", positive=True, finite=False)
    # an infinitely thick pixel lets nothing through; its thickness is kept out of the division, whose gradient
    # would be inf x 0 = NaN in every parameter (a NaN from pixels that take no part)
    thick = jnp.isfinite(thickness_mm)[..., None]
    ratio = jnp.where(thick, thickness_mm[..., None], 0.0) / scale_mm.reshape(1, 1, 3)
    atten = jnp.where(thick, jnp.exp(-ratio), 0.0)
    return light.colour.astype(dtype).reshape(1, 1, 3) * atten * (t_dir + ambient.reshape(1, 1, 3))


def _thickness_mm(buffers: Buffers, thickness: ParamLike | None, camera: Camera, shape: tuple[int, ...], dtype) -> Array:
    """Per-pixel thickness in mm: the thickness buffer (a negative value as 0, as every model reads it: the STA
    term's exp(-t / s) would grow without bound), else the constant ``thickness`` (scene units), else 0."""
    if buffers.thickness is not None:
        thick_units = clamp(buffers.thickness.astype(dtype), 0.0)
    elif thickness is not None:  # checked on the host by the callers; here where it is traced (inf: thick)
        thick_units = jnp.broadcast_to(checked(jnp.asarray(thickness, dtype), "thickness", finite=False), shape)
    else:
        thick_units = jnp.zeros(shape, dtype)
    # an infinite thickness stays infinite, kept out of the product (its gradient in mm_per_unit would be NaN)
    finite = jnp.isfinite(thick_units)
    return jnp.where(finite, jnp.where(finite, thick_units, 0.0) * camera.mm_per_unit.astype(dtype), jnp.inf)


@jax.jit
def _translucency_impl(buffers: Buffers, params: STAParams, camera: Camera, light: DirectionalLight,
                       thickness: ParamLike | None, material_albedo: Array | None) -> Array:
    dtype = _work_dtype(buffers.irradiance.dtype)
    if material_albedo is None:  # white: every material row
        material_albedo = jnp.ones((1, 3), buffers.irradiance.dtype)
    prep = _prepare(buffers, material_albedo, "post", dtype)
    normal = buffers.normal.astype(dtype) if buffers.normal is not None else normals_from_depth(prep.depth, camera)
    view = view_directions(prep.depth, camera)
    thick_mm = _thickness_mm(buffers, thickness, camera, prep.depth.shape, dtype)
    added = sta_term(normal, view, light, params, thick_mm)
    out = prep.albedo_out * (prep.irradiance + added)
    out = jnp.where(prep.valid[..., None], out, buffers.irradiance.astype(dtype))
    return as_output(out, buffers.irradiance.dtype)


def thin_transmittance(thickness_mm: ParamLike, d_mm: ParamLike) -> Array:
    """Thin-object transmittance of the normalised Burley profile: ``(exp(-t/d) + 3 exp(-t/(3d))) / 4``.

    The fraction of the profile's energy beyond radius t, ``1 - CDF(t)``: the profile's CCDF read as transmission
    through a slab of thickness t, a heuristic the engines share, not slab transport (docs/engines.md compares it with
    Monte Carlo). Unity HDRP ``ComputeTransmittanceDisney`` (``SubsurfaceScattering.hlsl``) evaluates this form with
    S = 1/d and multiplies it by ``0.25 * transmissionTint`` and later by the albedo. UE5 tabulates the same form
    (``BurleyNormalizedSSS.cpp`` ``Burley_TransmissionProfile``: ``0.25 A (exp(-S r / L) + 3 exp(-S r / (3 L)))``,
    L / S = d) but not at the same distances: ``ComputeTransmissionProfileBurley`` rescales them by
    ``0.1 / WorldUnitScale``, and by another 0.1 while ``r.SSProfiles.Transmission.UseLegacy`` is 1, so for the same
    material UE's transmission is this curve at a larger d (unverified against a UE render; docs/engines.md). It is
    not UE's diffuse-mean-free-path equivalence. Elementwise in (t, d), both in mm; d = 0 gives 0 for t > 0.
    """
    check_host_range(thickness_mm, "thickness_mm", finite=False)  # (NaN read as t = 0, T = 1; t < 0 as T = 1)
    check_host_range(d_mm, "d_mm")
    return burley_ccdf(thickness_mm, d_mm)


def _thin_model(thickness_mm: Array, albedo: Array, d_mm: Array) -> Array:
    return thin_transmittance(thickness_mm, d_mm)  # the profile's CCDF: the albedo plays no part


# transmittance T(thickness_mm, medium albedo, d_mm) of each physically based model, elementwise per channel
# (slab: the diffusely transmitted part only -- the unscattered beam reaches a camera only looking into the light)
_TRANSMITTANCE: dict[str, Callable[[Array, Array, Array], Array]] = {"thin": _thin_model,
                                                                      "slab": slab_diffuse_transmittance}


@eqx.filter_jit
def _transmission_impl(buffers: Buffers, material: BurleyMaterial, camera: Camera, light: DirectionalLight,
                       thickness: ParamLike | None, model: str, medium: MediumMaterial | None = None) -> Array:
    """``albedo * (irradiance + light * T * max(0, -N . L))`` ("thin", HDRP's convention), or
    ``albedo * irradiance + light * T_diffuse * max(0, -N . L) * P(N . V)`` ("slab": T_diffuse, the diffusely
    transmitted part, already holds all of the medium's absorption; P the exit distribution of the face; of
    ``medium`` where given, else the index-matched medium)."""
    dtype = _work_dtype(buffers.irradiance.dtype)
    prep = _prepare(buffers, material.albedo, "post", dtype)
    normal = buffers.normal.astype(dtype) if buffers.normal is not None else normals_from_depth(prep.depth, camera)
    thick_mm = clamp(_thickness_mm(buffers, thickness, camera, prep.depth.shape, dtype), 0.0)
    d = checked(material.d_mm.astype(dtype), "d_mm")[prep.rows]  # (H, W, 3)
    # the medium is the material's (its A and d per material id), not the albedo texture's, which only tints
    medium_albedo = clamp(material.albedo.astype(dtype), 0.0, 1.0)[prep.rows]
    t = jnp.where(jnp.isfinite(thick_mm), thick_mm, 0.0)[..., None]
    if medium is None:
        T = _TRANSMITTANCE[model](t, medium_albedo, d)
    else:
        T = medium.diffuse_transmittance(t[..., 0], prep.rows)
    transmitted = jnp.where(jnp.isfinite(thick_mm)[..., None], T, 0.0)
    # light reaching the back face: the cosine between the back-facing normal and the light
    back_cos = jnp.clip(jnp.sum(-normal * light.direction.astype(dtype).reshape(1, 1, 3), axis=-1), 0.0, 1.0)
    if model == "slab":
        # the view-dependent exit of diffuse light through the front face, as the slab lets it out: limb-brightened
        # when thin, peaked towards the normal when thick and absorbing (Fresnel, refraction; Lambertian is 1)
        view = view_directions(prep.depth, camera)
        mu_view = jnp.clip(jnp.sum(normal * view, axis=-1), 0.0, 1.0)
        # from a table per material row and channel (alpha and eta are the row's), interpolated per pixel
        if medium is None:
            tau, _ = slab_optical(t, medium_albedo, d)
            alb = clamp(material.albedo.astype(dtype), 0.0, 1.0).reshape(-1, 3)
            table = slab_exit_table(slab_optical(jnp.ones_like(alb), alb, jnp.ones_like(alb))[1],
                                    jnp.ones(alb.shape[:1], dtype))
        else:
            tau, _, _ = medium.optical(t[..., 0], prep.rows)
            table = slab_exit_table(medium.albedo_ss.astype(dtype), medium.eta.astype(dtype))
        transmitted = transmitted * slab_exit_lookup(table, prep.rows, tau, back_cos, mu_view)
    added = light.colour.astype(dtype).reshape(1, 1, 3) * transmitted * back_cos[..., None]
    out = prep.albedo_out * (prep.irradiance + (added if model == "thin" else 0.0)) + (added if model == "slab" else 0.0)
    out = jnp.where(prep.valid[..., None], out, buffers.irradiance.astype(dtype))
    return as_output(out, buffers.irradiance.dtype)


TRANSLUCENCY_MODELS = ("sta", "thin", "slab")


def translucency(
    buffers: Buffers,
    params: STAParams | BurleyMaterial | MediumMaterial,
    camera: Camera,
    light: DirectionalLight,
    *,
    albedo: ParamLike | None = None,
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
    - ``model="slab"``: slab transport, ``light * T_d * max(0, -N . L) * P(N . V)`` added to ``albedo *
      irradiance``: T_d, the fraction of a normal back light that leaves the front face after scattering, already
      holds all absorption (no albedo factor). Only the diffusely transmitted light: the unscattered (collimated)
      beam keeps the light's direction and reaches the camera only where it looks into the light, which a
      screen-space pass does not draw. ``P`` (``_slab.slab_exit``, read from a table per material row) spreads it
      over view directions as this slab lets it out: limb-brightened when thin, peaked towards the normal when thick
      and absorbing (the emergent radiance of the scattering source for the slab's optical thickness, albedo and the
      light's angle; Fresnel and refraction at the medium's eta; 1 would be Lambertian), with V towards the camera.
      With ``params`` a ``MediumMaterial`` (a preset that carries its medium: ``load_preset(...).medium``) T_d is
      that of the measured medium with its boundaries (``MediumMaterial.diffuse_transmittance``); with a
      ``BurleyMaterial``, ``slab_diffuse_transmittance(thickness_mm, A, d)``, the index-matched medium rebuilt from A
      and d (eta 1).
    """
    if model not in TRANSLUCENCY_MODELS:
        raise ValueError(f"model={model!r} is not one of {TRANSLUCENCY_MODELS}")
    check_one_image("translucency", buffers, getattr(params, "count", None), camera=camera)
    # the same ranges the batch and the CLI check: out of range, the added light explodes (7e16 from albedo 40)
    if albedo is not None:
        check_host_range(albedo, "albedo", high=1.0, finite=False)
    if thickness is not None and _is_concrete(thickness) and (
            is_bool(thickness) or not np.all(np.asarray(thickness, np.float64) >= 0)):
        raise ValueError(f"thickness must be >= 0 scene units (inf: infinitely thick), got {thickness!r}")
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
    # NumPy (no eager dispatch per call, and nothing a trace around the call could stage): the jitted pass takes it;
    # none (white) is built inside it, a constant of the program (a host table would be copied in on every call)
    if albedo is None:
        table = None
    elif _is_concrete(albedo):
        table = np.reshape(np.asarray(albedo), (-1, 3))
    else:
        table = jnp.reshape(jnp.asarray(albedo), (-1, 3))
    return _translucency_impl(buffers, params, camera, light, thickness, table)
