"""Blender Cycles: the Principled BSDF's subsurface (Christensen–Burley, Random Walk, Random Walk (Skin)).

The closure radius is ``Subsurface Radius * Subsurface Scale`` (scene units; blender/blender
``intern/cycles/kernel/svm/closure.h``: ``bssrdf->radius = max(subsurface_radius * subsurface_scale, 0)``) and its
albedo the (clamped) Base Color / Subsurface Color. What Cycles does with them depends on the method and the version
(``intern/cycles/kernel/closure/bssrdf.h``, ``bssrdf_setup_radius``; ``intern/cycles/kernel/integrator/
subsurface_random_walk.h``, ``subsurface_random_walk_remap``):

| method (``--method``) | UI name | radius after setup | rendered |
|---|---|---|---|
| ``burley`` 2.80–2.93 | Christensen-Burley | ``l / s_dt(A)``, ``l = r / (4 pi)`` (``bssrdf_burley_setup``) | Burley with that d |
| ``burley`` >= 3.0 | Christensen-Burley | ``r / (4 pi)`` (``bssrdf_setup_radius``, ``0.25f * M_1_PI_F``) | Burley with that d |
| ``random-walk`` 2.80–2.93 | Random Walk | ``l / s_dt(A)``; the remap multiplies by ``s_dt(A)`` again | walk, mean free path ``r / (4 pi)`` |
| ``random-walk`` 3.x / >= 4.0 | Random Walk (Fixed Radius) / Random Walk | ``r / (4 pi)`` | walk, mean free path ``r / (4 pi)`` |
| ``random-walk-skin`` 3.x / >= 4.0 | Random Walk / Random Walk (Skin) | ``r sqrt(3 (1 - a'))``, ``a'``: dipole albedo of A at the IOR | walk, that mean free path |

A random walk's profile is the walk's, not Burley's: its d here is the Burley profile the memo fits to light that
enters through a diffusely transmitting surface, ``d = l / s_dt(A)`` (Christensen & Burley 2015, eq. 6, the
configuration of Cycles' walk: cosine-weighted entry, exit where the walk meets the surface); tests/test_engines.py
measures it against the project's Monte Carlo of the medium Cycles walks. So with the same radius, Random Walk renders
``s_dt(A)`` = 1.04 (A = 1) to 4.14 (A = 0) times narrower than Christensen-Burley.
"""

from __future__ import annotations

import math
import re
from typing import Any, ClassVar

import numpy as np

from ._base import ALBEDO_HELP, MM_PER_UNIT, AbstractEngine, Flag
from ._common import FOUR_PI, burley_cdf_np, burley_marginal_masses, material, rgb, s_fit, scalar

# The newest release whose sources were read for these rules, and the default of --blender-version.
CURRENT_BLENDER = "5.1"
METHODS = ("burley", "random-walk", "random-walk-skin")
BURLEY_TRUNCATE = 16.0  # bssrdf.h: BURLEY_TRUNCATE, the sampled radius ends at 16 d


def parse_version(version) -> tuple[int, int]:
    """``"4.2"``, ``"4.2.1"``, ``"2.93"`` (or the old ``cycles`` names ``"3.0+"``, ``"2.8"``) as (major, minor).
    A string only: a number cannot tell 2.9 from 2.90."""
    if not isinstance(version, str):
        raise TypeError(f"blender_version must be a string like '4.2' or '5.1' (a number cannot tell 2.9 from "
                         f"2.90), got {version!r}")
    text = version.strip().rstrip("+")
    if text == "2.8":
        return (2, 93)  # the old cycles="2.8" family: 2.80-2.93 share the rules
    if not re.fullmatch(r"\d+(\.\d+){0,2}", text):
        raise ValueError(f"blender_version must look like 4.2 or 5.1, got {version!r}")
    parts = text.split(".")
    major, minor = int(parts[0]), int(parts[1]) if len(parts) > 1 else 0
    if (major, minor) < (2, 80):
        raise ValueError(f"blender_version {version!r}: only Blender 2.80 and later are converted")
    return major, minor


def version_warning(version: tuple[int, int]) -> str | None:
    latest = parse_version(CURRENT_BLENDER)
    if version > latest:
        return (f"Blender {version[0]}.{version[1]} is newer than the sources these rules were read from "
                f"(<= {CURRENT_BLENDER}): {CURRENT_BLENDER}'s rules are used")
    return None


def method_ui_name(method: str, version: tuple[int, int]) -> str:
    """The Subsurface Method as Blender's UI names it in that version (3.x calls the skin method 'Random Walk')."""
    if method == "burley":
        return "Christensen-Burley"
    if method == "random-walk":
        return "Random Walk (Fixed Radius)" if (3, 0) <= version < (4, 0) else "Random Walk"
    return "Random Walk" if version < (4, 0) else "Random Walk (Skin)"


def _method_from_params(params: dict[str, Any], version: tuple[int, int]) -> str:
    if "method" in params:
        return _check_method(params["method"], version)
    ui = params.get("Subsurface Method", "Christensen-Burley")
    for m in METHODS:
        if method_ui_name(m, version) == ui:
            return _check_method(m, version)
    raise ValueError(f"Subsurface Method {ui!r} is not a Blender {version[0]}.{version[1]} method")


def _check_method(method: str, version: tuple[int, int]) -> str:
    if method not in METHODS:
        raise ValueError(f"method={method!r} is not one of {', '.join(METHODS)}")
    if method == "random-walk-skin" and version < (3, 0):
        raise ValueError("method 'random-walk-skin' needs Blender >= 3.0 (2.80-2.93 have Christensen-Burley and "
                         "Random Walk only)")
    return method


def default_ior(version: tuple[int, int]) -> float:
    """The IOR the skin method reads by default: 3.x's Subsurface IOR 1.4, 4.x's Principled IOR 1.5."""
    return 1.4 if version < (4, 0) else 1.5


# --- Random Walk (Skin): bssrdf_setup_radius's albedo- and IOR-dependent radius ------------------------------------


def _dipole_rd(alpha_prime: float, fourthird_a: float) -> float:
    # bssrdf.h, bssrdf_dipole_compute_Rd
    s = math.sqrt(3.0 * (1.0 - alpha_prime))
    return 0.5 * alpha_prime * (1.0 + math.exp(-fourthird_a * s)) * math.exp(-s)


def _dipole_alpha_prime(rd: float, fourthird_a: float) -> float:
    # bssrdf.h, bssrdf_dipole_compute_alpha_prime: 12 bisection steps, as Cycles does (its result, not the root)
    if rd < 1e-4:
        return 0.0
    if rd >= 0.995:
        return 0.999999
    x0, x1 = 0.0, 1.0
    xmid = 0.5
    for _ in range(12):
        xmid = 0.5 * (x0 + x1)
        if _dipole_rd(xmid, fourthird_a) < rd:
            x0 = xmid
        else:
            x1 = xmid
    return xmid


def skin_radius_factor(albedo, ior: float) -> np.ndarray:
    """``sqrt(3 (1 - a'))`` per channel: Random Walk (Skin)'s radius factor (bssrdf.h ``bssrdf_setup_radius``;
    ``F_dr`` from Jensen's fit at the IOR, clamped to [1.01, 3.8] by ``bssrdf_setup``, ``a'`` the dipole albedo whose
    diffuse reflectance is A)."""
    eta = min(max(float(ior), 1.01), 3.8)
    inv = 1.0 / eta
    f_dr = inv * (-1.440 * inv + 0.710) + 0.668 + 0.0636 * eta
    fourthird_a = (4.0 / 3.0) * (1.0 + f_dr) / (1.0 - f_dr)
    a = np.asarray(albedo, np.float64)
    return np.array([math.sqrt(3.0 * (1.0 - _dipole_alpha_prime(float(x), fourthird_a))) for x in a])


def random_walk_single_scattering_albedo(albedo, version: tuple[int, int] = (5, 1)) -> np.ndarray:
    """The single-scattering albedo Cycles' walk uses for surface albedo A (isotropic phase function).

    >= 3.0: ``subsurface_random_walk_remap`` (Wrenninge, Villemin & Hery's fit at g = 0): ``b = A^(1/4)``,
    ``alpha = (1 - b) 1.8260523782 atan(5.11246790329 A)^1.09686102424 + b 0.496310210422 atan(4.2350090365 A)^
    2.40602999408``, clamped to [0, 0.999999]; 2.80–2.93: ``1 - exp(A (-5.09406 + A (2.61188 - 4.31805 A)))``.
    ``subsurface_random_walk_coefficients`` then raises alpha below 0.2 to 0.2 and lowers the throughput to match.
    """
    a = np.asarray(albedo, np.float64)
    if version < (3, 0):
        return 1.0 - np.exp(a * (-5.09406 + a * (2.61188 - a * 4.31805)))
    b_coef = 4.98511194385 + 0.127355959438  # B(g = 0): 4.985... + 0.1273... exp(0)
    e_coef = 4.23190299701 + 0.00310603949088  # E(g = 0)
    blend = a**0.25
    alpha = ((1.0 - blend) * 1.8260523782 * np.arctan(b_coef * a) ** 1.09686102424
             + blend * 0.496310210422 * np.arctan(e_coef * a) ** 2.40602999408)
    return np.clip(alpha, 0.0, 0.999999)


def _mfp_per_radius(albedo: np.ndarray, method: str, version: tuple[int, int], ior: float) -> np.ndarray:
    """The length Cycles works with per unit of ``radius * scale``: Burley's d, or the walk's mean free path."""
    if method == "random-walk-skin":
        return skin_radius_factor(albedo, ior)
    base = np.full(3, 1.0 / FOUR_PI)
    if method == "burley" and version < (3, 0):
        return base / s_fit("diffuse_transmission", albedo)
    return base  # burley >= 3.0; random-walk in every version (2.8x: l / s in setup, times s in the remap)


def _d_per_radius(albedo, method, version, ior) -> np.ndarray:
    per = _mfp_per_radius(albedo, method, version, ior)
    return per if method == "burley" else per / s_fit("diffuse_transmission", albedo)


def random_walk_medium(subsurface_color, subsurface_radius, *, subsurface_scale: float = 1.0,
                       mm_per_unit: float = 1000.0, method: str = "random-walk", blender_version=CURRENT_BLENDER,
                       ior: float | None = None) -> dict[str, np.ndarray]:
    """The homogeneous medium Cycles' random walk traces for a Principled BSDF: ``single_scattering_albedo`` (3,) and
    ``mean_free_path_mm`` (3,) (``1 / sigma_t``), isotropic, index-matched boundary, cosine-weighted entry (the
    skin method enters by a rough refraction instead). What ``sss_jax._montecarlo`` can walk to check the d here."""
    albedo = rgb("subsurface_color", subsurface_color, lo=0.0, hi=1.0)
    radius = rgb("subsurface_radius", subsurface_radius, lo=0.0)
    version = parse_version(blender_version)
    method = _check_method(method, version)
    if method == "burley":
        raise ValueError("method 'burley' is not a random walk")
    ior = default_ior(version) if ior is None else scalar("ior", ior)
    mfp = radius * scalar("subsurface_scale", subsurface_scale) * scalar("mm_per_unit", mm_per_unit) * \
        _mfp_per_radius(albedo, method, version, ior)
    return {"single_scattering_albedo": random_walk_single_scattering_albedo(albedo, version), "mean_free_path_mm": mfp}


# The Principled BSDF inputs both EEVEE engines read (one list: the Blender node, whichever EEVEE renders it)
EEVEE_FLAGS: tuple[Flag, ...] = (
    Flag("--albedo", ALBEDO_HELP, key="Subsurface Color", required=True),
    Flag("--radius", "blender/eevee/eevee-next: Subsurface Radius, scene units", key="Subsurface Radius",
         required=True),
    Flag("--scale", "blender/eevee/eevee-next: Subsurface Scale (default 1)", key="Subsurface Scale",
         option="subsurface_scale", kind="float"),
    Flag("--blender-version", "blender/eevee/eevee-next: Blender version", key="blender_version",
         option="blender_version", kind="str"),
    MM_PER_UNIT,
)


class Blender(AbstractEngine):
    """Cycles (Principled BSDF, any subsurface method)."""

    name: ClassVar[str] = "blender"
    title: ClassVar[str] = "Blender Cycles (Principled BSDF)"
    default_mm_per_unit: ClassVar[float] = 1000.0
    kernel: ClassVar[str | None] = "cycles"
    lossy: ClassVar[str | None] = None
    source: ClassVar[str] = ("blender/blender intern/cycles/kernel/closure/bssrdf.h (bssrdf_setup_radius, "
                             "bssrdf_burley_setup, bssrdf_dipole_compute_alpha_prime; 2.80-2.93, 3.0-3.6, 4.0-5.1), "
                             "intern/cycles/kernel/integrator/subsurface_random_walk.h (subsurface_random_walk_remap, "
                             ">= 3.0), intern/cycles/kernel/svm/closure.h (radius * scale)")
    flags: ClassVar[tuple[Flag, ...]] = (
        Flag("--albedo", ALBEDO_HELP, key="Subsurface Color", required=True),
        Flag("--radius", "blender/eevee/eevee-next: Subsurface Radius, scene units", key="Subsurface Radius",
             required=True),
        Flag("--scale", "blender/eevee/eevee-next: Subsurface Scale (default 1)", key="Subsurface Scale",
             option="subsurface_scale", kind="float"),
        Flag("--method", "blender: Cycles' Subsurface Method (default burley; Blender's own default is Random Walk)",
             key="method", option="method", kind="str", choices=METHODS),
        Flag("--blender-version", f"blender/eevee/eevee-next: Blender version (default {CURRENT_BLENDER})",
             key="blender_version", option="blender_version", kind="str"),
        Flag("--ior", "blender: IOR the Random Walk (Skin) method reads (default 1.4 in 3.x, 1.5 from 4.0)",
             key="IOR", option="ior", kind="float"),
        MM_PER_UNIT,
    )

    def to_engine(self, albedo, d_mm, *, subsurface_scale: float = 1.0, mm_per_unit: float = 1000.0,
                  method: str = "burley", blender_version=CURRENT_BLENDER, ior: float | None = None,
                  cycles: str | None = None) -> dict[str, Any]:
        """Principled BSDF inputs that render ``(albedo, d_mm)`` with ``method`` in ``blender_version`` (``cycles``:
        the old name of the version family, ``"3.0+"`` or ``"2.8"``)."""
        albedo, d = material(albedo, d_mm)
        scale = scalar("subsurface_scale", subsurface_scale)
        unit = scalar("mm_per_unit", mm_per_unit)
        version = parse_version(cycles if cycles is not None else blender_version)
        method = _check_method(method, version)
        ior = default_ior(version) if ior is None else scalar("ior", ior)
        radius = d / (_d_per_radius(albedo, method, version, ior) * scale * unit)
        out = {"Subsurface Color": albedo.tolist(), "Subsurface Radius": radius.tolist(), "Subsurface Scale": scale,
               "Subsurface Method": method_ui_name(method, version), "method": method, "mm_per_unit": unit,
               "blender_version": f"{version[0]}.{version[1]}"}
        if method == "random-walk-skin":
            out["IOR"] = ior
        warning = version_warning(version)
        if warning:
            out["warnings"] = [warning]
        return out

    def from_engine(self, params: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        for key in ("Subsurface Color", "Subsurface Radius"):
            if key not in params:
                raise ValueError(f"blender parameters need {key!r}")
        albedo = rgb("subsurface_color", params["Subsurface Color"], lo=0.0, hi=1.0)
        radius = rgb("subsurface_radius", params["Subsurface Radius"], lo=0.0)
        scale = scalar("subsurface_scale", params.get("Subsurface Scale", 1.0), positive=False, lo=0.0)
        unit = scalar("mm_per_unit", params.get("mm_per_unit", 1000.0))
        version = parse_version(params.get("blender_version", params.get("cycles", CURRENT_BLENDER)))
        method = _method_from_params(params, version)
        ior = params.get("IOR")
        ior = default_ior(version) if ior is None else scalar("ior", ior)
        with np.errstate(over="ignore"):  # an overflow is inf, which the material's own check names
            return albedo, radius * scale * unit * _d_per_radius(albedo, method, version, ior)

    def block(self, albedo, d_mm, **options) -> dict[str, Any]:
        """Random Walk (Cycles' default method) in the current release, with the radius every method needs."""
        options = {"method": "random-walk", **options}
        out = super().block(albedo, d_mm, **options)
        out["Subsurface Radius by method"] = {
            method_ui_name(m, parse_version(out["blender_version"])):
                self.to_engine(albedo, d_mm, **{**options, "method": m, "mm_per_unit": out["mm_per_unit"]})[
                    "Subsurface Radius"] for m in METHODS}
        return out

    def notes(self, params: dict[str, Any]) -> dict[str, str | None]:
        try:
            version = parse_version(params.get("blender_version", params.get("cycles", CURRENT_BLENDER)))
            method = _method_from_params(params, version)
        except ValueError:
            method = "burley"
        if method != "burley":
            return {"lossy": "a random walk renders its own profile, not Burley's: d is the Burley profile the memo "
                             "fits to it (d = l / s_dt(A)), within the error docs/engines.md measures against Monte "
                             "Carlo", "unverified": None, "note": None}
        return {"lossy": None, "unverified": None,
                "note": "Christensen-Burley. Cycles' default Subsurface Method is Random Walk, which renders the same "
                        "radius s_dt(A) = 1.04-4.1 times narrower: convert with method 'random-walk' if the material "
                        "uses it"}

    def marginal(self, albedo, d_mm, edges, params=None):
        """Christensen-Burley as Cycles samples it: truncated at 16 d and renormalised (``bssrdf_burley_pdf``). The
        random walks have no closed-form kernel (docs/engines.md measures them against Monte Carlo)."""
        d = np.asarray(d_mm, np.float64)
        return burley_marginal_masses(d, edges, u_max=burley_cdf_np(BURLEY_TRUNCATE * d, d)), np.asarray(albedo)
