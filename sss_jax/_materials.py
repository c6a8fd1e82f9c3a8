"""Parameter pytrees of the techniques: small frozen equinox Modules, one row per material.

A material table holds ``M`` materials as arrays with a leading axis ``(M, 3)``; a frame's ``material_id`` buffer
selects row ``id - 1`` (id 0 means "no subsurface scattering here"). With ``M = 1`` every non-zero id uses the one
material. Constructors accept ``(3,)`` for a single material. Lengths are in millimetres.

Value checks run in ``__check_init__`` when the values are concrete (outside ``jit``); inside ``jit`` the techniques
check with ``eqx.error_if`` so a NaN or negative parameter is an error, not a NaN image.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._checks import check_host_range, checked, clamp, is_bool
from ._custom_types import ParamLike
from ._kernels import (
    SeparableKernel,
    profile_half_masses,
    separable_kernel_from_profile,
    two_gaussian_half_masses,
    two_gaussian_kernel,
)
from ._profiles import (
    AbstractProfile,
    BurleyProfile,
    burley_cdf,
    burley_inverse_ccdf,
    burley_R,
    d_from_mfp,
)

__all__ = ["AbstractMaterial", "BurleyMaterial", "TwoGaussianMaterial", "ProfileMaterial", "STAParams",
           "DirectionalLight"]


def _table(name: str, value: ParamLike, dtype=None) -> Array:
    if is_bool(value):  # True would read as 1.0
        raise TypeError(f"{name} must be numbers, not bools, got {value!r}")
    x = jnp.asarray(value, dtype=dtype)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.float32)
    if x.ndim == 0:
        x = jnp.broadcast_to(x, (1, 3))
    elif x.ndim == 1:
        if x.shape[0] != 3:
            raise ValueError(f"{name} must have 3 values (R, G, B), got shape {x.shape}")
        x = x[None, :]
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"{name} must have shape (3,) or (M, 3), got {x.shape}")
    return x


def _is_concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _same_rows(*named: tuple[str, Array]) -> None:
    rows = {n: a.shape[0] for n, a in named}
    if len(set(rows.values())) > 1:
        raise ValueError(f"material parameters must have the same number of materials (rows): {rows}")


class AbstractMaterial(eqx.Module):
    """A table of scattering materials (one row per material, ``albedo (M, 3)``) that answers for its own kernels, so
    the techniques never test a material's type (equinox's abstract/final pattern).

    - ``separable_kernels(taps, dtype)``: each material's 1D separable kernel (offsets (M, n) mm, weights (M, n, 3)).
    - ``separable_half_masses(unit_x, dtype)``: each kernel's mass over ``[0, x]`` at unit positions ``unit_x (K,)``
      (times its reach), ``(M, 3, K)``, from the same profile as its weights: what a kernel cut at the frame is
      re-integrated from.
    - ``kernel_parameters()``: the arrays that decide the kernel (materials with equal rows share one), or ``None``.
    - ``radius_mm(energy)``: host side, the radius (mm) holding ``energy`` of the widest channel of any material.
    - ``pixel_profile(rows, valid, dtype)``: ``(radial, cdf)`` of each pixel's own material (row ``rows (H, W)``),
      ``r (H, W) -> (H, W, 3)``; invalid pixels get the empty profile where the material varies per pixel.
    """

    albedo: eqx.AbstractVar[Array]

    @property
    def count(self) -> int:
        return int(self.albedo.shape[0])

    def separable_kernels(self, taps: int, dtype) -> SeparableKernel:
        raise NotImplementedError

    def separable_half_masses(self, unit_x: np.ndarray, dtype) -> Array:
        raise NotImplementedError

    def kernel_parameters(self) -> list[Array] | None:
        return None

    def radius_mm(self, energy: float) -> float:
        raise TypeError(f"{type(self).__name__} has no radial profile")

    def pixel_profile(self, rows: Array, valid: Array, dtype):
        raise TypeError(f"{type(self).__name__} has no radial profile")


class BurleyMaterial(AbstractMaterial):
    """Christensen–Burley material: surface albedo ``A`` in [0, 1] and scattering distance ``d_mm`` >= 0 (mm)."""

    albedo: Float[Array, "M 3"]
    d_mm: Float[Array, "M 3"]

    def __init__(self, albedo: ParamLike, d_mm: ParamLike):
        self.d_mm = _table("d_mm", d_mm)
        self.albedo = _table("albedo", albedo, self.d_mm.dtype)
        if self.albedo.shape[0] == 1 and self.d_mm.shape[0] > 1:
            self.albedo = jnp.broadcast_to(self.albedo, self.d_mm.shape)

    def __check_init__(self):
        _same_rows(("albedo", self.albedo), ("d_mm", self.d_mm))
        check_host_range(self.albedo, "albedo", high=1.0, finite=False)
        check_host_range(self.d_mm, "d_mm")

    @classmethod
    def from_mfp(cls, albedo: ParamLike, mfp_mm: ParamLike, *, fit: str = "diffuse_transmission") -> "BurleyMaterial":
        """From albedo and mean free path (mm) through the memo's ``s(A)`` fit (``d = mfp / s(A)``)."""
        a = _table("albedo", albedo)
        l = _table("mfp_mm", mfp_mm, a.dtype)
        check_host_range(l, "mfp_mm", finite=False)
        return cls(a, d_from_mfp(a, l, fit=fit))

    def separable_kernels(self, taps: int, dtype) -> SeparableKernel:
        d = checked(self.d_mm.astype(dtype), "d_mm")
        return jax.vmap(lambda row: separable_kernel_from_profile(BurleyProfile(row), taps=taps))(d)

    def separable_half_masses(self, unit_x: np.ndarray, dtype) -> Array:
        d = checked(self.d_mm.astype(dtype), "d_mm")
        return jax.vmap(lambda row: profile_half_masses(BurleyProfile(row), unit_x).T)(d)

    def kernel_parameters(self) -> list[Array]:
        return [self.d_mm]

    def radius_mm(self, energy: float) -> float:
        return float(np.max(np.asarray(burley_inverse_ccdf(1 - energy, np.asarray(self.d_mm, np.float64)))))

    def pixel_profile(self, rows: Array, valid: Array, dtype):
        d_pix = jnp.where(valid[..., None], checked(self.d_mm.astype(dtype), "d_mm")[rows], 0.0)
        return (lambda r: burley_R(r[..., None], d_pix)), (lambda r: burley_cdf(r[..., None], d_pix))


class TwoGaussianMaterial(AbstractMaterial):
    """Jimenez et al.'s artist-friendly separable kernel per channel: ``w G(sigma_near) + (1 - w) G(sigma_far)``.

    ``w`` in [0, 1]; ``sigma_near_mm``, ``sigma_far_mm`` >= 0 in mm (0 is the identity kernel).
    """

    albedo: Float[Array, "M 3"]
    w: Float[Array, "M 3"]
    sigma_near_mm: Float[Array, "M 3"]
    sigma_far_mm: Float[Array, "M 3"]

    def __init__(self, albedo: ParamLike, w: ParamLike, sigma_near_mm: ParamLike, sigma_far_mm: ParamLike):
        self.w = _table("w", w)
        dtype = self.w.dtype
        self.sigma_near_mm = _table("sigma_near_mm", sigma_near_mm, dtype)
        self.sigma_far_mm = _table("sigma_far_mm", sigma_far_mm, dtype)
        albedo = _table("albedo", albedo, dtype)
        if albedo.shape[0] == 1 and self.w.shape[0] > 1:
            albedo = jnp.broadcast_to(albedo, self.w.shape)
        self.albedo = albedo

    def __check_init__(self):
        _same_rows(("albedo", self.albedo), ("w", self.w), ("sigma_near_mm", self.sigma_near_mm),
                   ("sigma_far_mm", self.sigma_far_mm))
        check_host_range(self.albedo, "albedo", high=1.0, finite=False)
        check_host_range(self.w, "w", high=1.0, finite=False)
        # finite: an inf sigma failed later, inside the pass's jit
        check_host_range(self.sigma_near_mm, "sigma_near_mm")
        check_host_range(self.sigma_far_mm, "sigma_far_mm")

    def _kernel_rows(self, dtype) -> tuple[Array, Array, Array]:
        """``w`` (clipped to [0, 1]), ``sigma_near_mm`` and ``sigma_far_mm`` (checked) as the kernels take them."""
        return (clamp(self.w.astype(dtype), 0.0, 1.0), checked(self.sigma_near_mm.astype(dtype), "sigma_near_mm"),
                checked(self.sigma_far_mm.astype(dtype), "sigma_far_mm"))

    def separable_kernels(self, taps: int, dtype) -> SeparableKernel:
        return jax.vmap(lambda a, b, c: two_gaussian_kernel(a, b, c, taps=taps))(*self._kernel_rows(dtype))

    def separable_half_masses(self, unit_x: np.ndarray, dtype) -> Array:
        return jax.vmap(lambda a, b, c: two_gaussian_half_masses(a, b, c, unit_x).T)(*self._kernel_rows(dtype))

    def kernel_parameters(self) -> list[Array]:
        return [self.w, self.sigma_near_mm, self.sigma_far_mm]


class ProfileMaterial(AbstractMaterial):
    """Any radial profile (Gaussian sum, tabulated Monte Carlo) with a surface albedo: one material.

    Used by ``separable`` (pre-integrated kernel) and ``reference``.
    """

    albedo: Float[Array, "1 3"]
    profile: AbstractProfile

    def __init__(self, profile: AbstractProfile, albedo: ParamLike | None = None):
        if profile.num_channels != 3:
            raise ValueError(f"ProfileMaterial needs a 3-channel profile, got {profile.num_channels} channels")
        self.profile = profile
        self.albedo = _table("albedo", profile.albedo if albedo is None else albedo)

    def __check_init__(self):
        check_host_range(self.albedo, "albedo", high=1.0, finite=False)

    def separable_kernels(self, taps: int, dtype) -> SeparableKernel:
        k = separable_kernel_from_profile(self.profile, taps=taps)
        return SeparableKernel(offsets_mm=k.offsets_mm[None].astype(dtype), weights=k.weights[None].astype(dtype))

    def separable_half_masses(self, unit_x: np.ndarray, dtype) -> Array:
        return profile_half_masses(self.profile, unit_x).T[None].astype(dtype)

    def radius_mm(self, energy: float) -> float:
        return float(np.max(np.asarray(self.profile.radius_for_energy(energy))))

    def pixel_profile(self, rows: Array, valid: Array, dtype):
        return self.profile.radial, self.profile.cdf


class STAParams(eqx.Module):
    """The simple translucency approximation (Barré-Brisebois & Bouchard, GDC 2011; the paper's Sec. 3.1).

    - ``distortion`` d_T (unitless, >= 0): how far the normal bends the light vector, ``L_T = norm(L + d_T N)``.
    - ``power`` p_T (>= 0) and ``scale`` s_T (3,) (>= 0): ``T_dir = s_T max(0, V . -L_T)^p_T``.
    - ``ambient`` a_T (3,) (>= 0): view-independent back-light.
    - ``thickness_mm`` (3,) (> 0): the mapping from thickness to attenuation, ``t(x) = exp(-thickness / thickness_mm)``
      per channel (1 for a paper-thin sheet, 0 for a thick body); thickness comes from the buffer (scene units).

    STA adds light: ``out = diffuse + albedo * light * A_L * t * (T_dir + a_T)``; it does not conserve energy.
    """

    distortion: Float[Array, ""]
    power: Float[Array, ""]
    scale: Float[Array, " 3"]
    ambient: Float[Array, " 3"]
    thickness_mm: Float[Array, " 3"]

    def __init__(self, *, distortion=0.2, power=4.0, scale=1.0, ambient=0.0, thickness_mm=1.0, dtype=None):
        given = {"distortion": distortion, "power": power, "scale": scale, "ambient": ambient,
                 "thickness_mm": thickness_mm}
        arrays = {}
        for name, value in given.items():  # each named where it is not a number (a string, None, a bool)
            if is_bool(value):
                raise TypeError(f"STAParams: {name} must be a number, not a bool, got {value!r}")
            try:
                arrays[name] = jnp.asarray(value)
            except TypeError:
                raise TypeError(f"STAParams: {name} must be a number, got {value!r}") from None
            if not jnp.issubdtype(arrays[name].dtype, jnp.number):
                raise TypeError(f"STAParams: {name} must be a number, got {value!r}")
        if dtype is None:  # follow the inputs (float64 under x64), at least float32
            dtype = jnp.result_type(*(a.dtype for a in arrays.values()), jnp.float32)
        elif not jnp.issubdtype(dtype, jnp.floating):  # an int32 table would read 0.7 as 0
            raise TypeError(f"STAParams: dtype must be a floating type, got {dtype!r}")
        for name in ("distortion", "power"):  # one number: a per-channel value would bend the normal's x, y, z
            if arrays[name].ndim != 0:
                raise ValueError(f"STAParams: {name} must be one number (it is not per channel), got shape "
                                 f"{arrays[name].shape}")
        for name in ("scale", "ambient", "thickness_mm"):
            if arrays[name].shape not in ((), (1,), (3,)):
                raise ValueError(f"STAParams: {name} must be one number or 3 (R, G, B), got shape "
                                 f"{arrays[name].shape}")
        self.distortion = arrays["distortion"].astype(dtype)
        self.power = arrays["power"].astype(dtype)
        self.scale = jnp.broadcast_to(arrays["scale"].astype(dtype), (3,))
        self.ambient = jnp.broadcast_to(arrays["ambient"].astype(dtype), (3,))
        self.thickness_mm = jnp.broadcast_to(arrays["thickness_mm"].astype(dtype), (3,))

    def __check_init__(self):
        # finite: an inf scale, power or light makes an inf or NaN image, not a bright one
        for name in ("distortion", "power", "scale", "ambient"):
            check_host_range(getattr(self, name), name)
        check_host_range(self.thickness_mm, "thickness_mm", low_open=True, finite=False)  # inf: paper-thin


class DirectionalLight(eqx.Module):
    """A directional light in camera space (x right, y down, z forward): ``direction`` points from the surface
    towards the light; ``colour`` is its irradiance at normal incidence (linear RGB)."""

    direction: Float[Array, " 3"]
    colour: Float[Array, " 3"]

    def __init__(self, direction: ParamLike, colour: ParamLike = (1.0, 1.0, 1.0)):
        for name, value in (("direction", direction), ("colour", colour)):
            if is_bool(value):
                raise TypeError(f"light {name} must be numbers, not bools, got {value!r}")
        direction = jnp.asarray(direction, dtype=jnp.result_type(jnp.asarray(direction).dtype, jnp.float32))
        if direction.shape != (3,):
            raise ValueError(f"light direction must have shape (3,), got {direction.shape}")
        if np.shape(colour) not in ((), (1,), (3,)):
            raise ValueError(f"light colour must be one number or 3 (R, G, B), got shape {np.shape(colour)}")
        if _is_concrete(direction):
            n = float(np.linalg.norm(np.asarray(direction)))
            if not np.isfinite(n) or n == 0:
                raise ValueError(f"light direction must be a finite non-zero vector, got {np.asarray(direction)}")
        self.direction = direction / jnp.linalg.norm(direction)
        self.colour = jnp.broadcast_to(jnp.asarray(colour, dtype=direction.dtype), (3,))

    def __check_init__(self):
        check_host_range(self.colour, "light colour")
