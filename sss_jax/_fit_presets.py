"""Artist presets: measured and artist-authored materials fitted once, saved as ``fits/<material>.json``.

Where the numbers come from (one derivation per kind of source, both documented in ``fits/README.md``):

- **measured** materials (Jensen et al. 2001, Table 2: reduced scattering ``sigma_s'`` and absorption ``sigma_a`` in
  1/mm per channel, index of refraction 1.3; ``data/measured_materials.csv``): the volume mean free path
  ``l = 1 / (sigma_s' + sigma_a)`` and single-scattering albedo ``alpha' = sigma_s' / (sigma_s' + sigma_a)``
  (similarity theory: isotropic scattering with the reduced coefficients); the surface albedo ``A`` is the total
  diffuse reflectance of a Monte Carlo random walk in that medium (pencil beam, eta = 1.3, specular reflection
  excluded), and ``d = l / s(A)`` with the memo's searchlight fit ``s(A) = 1.85 - A + 7 |A - 0.8|^3``
  (Christensen & Burley 2015, Eq. 6: the fit for normal incidence with the mean free path as the length).
- **artist** materials (surface albedo ``A`` and Burley's ``d`` per channel, as artists set them in Blender,
  HDRP or UE): the medium behind them is the one with an index-matched boundary whose pencil-beam total reflectance
  is ``A``. For isotropic scattering that is exact: ``A = 1 - H(1) sqrt(1 - alpha)`` with Chandrasekhar's H-function
  (Radiative Transfer, 1960, Ch. V; the plane albedo of a semi-infinite atmosphere), inverted for ``alpha``;
  ``l = d s(A)``. The Monte Carlo run of that medium then checks the inversion (its total reflectance must be ``A``).

Each preset then holds Burley's d, the two-Gaussian kernel fitted to the Burley profile (and one fitted to the Monte
Carlo profile), the STA parameters fitted to slab transmission, the error of each cheap model against Burley and
against Monte Carlo with the metric named, every fit's record, an engine block per engine (``engines``), and the
taps of the two-Gaussian kernel as HLSL and GLSL arrays. Monte Carlo runs are cached in ``fits/montecarlo/`` with
their provenance (photons, seed, version) and reused only when all of it matches.
"""

from __future__ import annotations

import csv
import json
import math
import os
import pathlib
import sys
import time
from collections.abc import Callable, Iterable
from importlib import resources
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._version import __version__
from ._fitting import (
    RENDERED_HALF_PX,
    RENDERED_PIXEL_PER_D,
    burley_slab_transmittance,
    fit_sta,
    fit_two_gaussian_profile,
    fit_two_gaussian_to_burley,
    image_error,
    image_patterns,
    rendered_kernel_errors,
    sta_slab_response,
)
from ._io import SSSInputError, write_bytes_atomic
from ._kernels import two_gaussian_kernel
from ._materials import BurleyMaterial, ProfileMaterial, STAParams, TwoGaussianMaterial
from ._metrics import rel_l2
from ._montecarlo import MCResult, simulate, to_tabulated_profile
from ._profiles import BurleyProfile, burley_R, marginal_cdf, scaling_searchlight
from ._scene import Camera
from ._techniques import reference

__all__ = [
    "ARTIST_MATERIALS",
    "albedo_from_surface_albedo",
    "chandrasekhar_h",
    "export_taps",
    "fit_preset",
    "fit_presets",
    "material_names",
    "material_source",
    "measured_materials",
    "write_presets_readme",
]

# Artist materials: surface albedo A and Burley d (mm) per channel, the way artists set them (Blender's subsurface
# colour and radius, HDRP's scattering distance). Values chosen by look, not measured: skin after the red-dominant
# spread of measured skin (d_r about 4x d_b; cf. skin1/skin2 of Jensen et al. 2001); marble a bright, long, near-grey
# spread; jade green with its longest spread in green; wax warm and deep in red; milk bright with a blue-shifted
# short spread relative to the red. The artist marble is "marble_artist": "marble" is the measured one of the table.
ARTIST_MATERIALS: dict[str, dict[str, list[float]]] = {
    "skin": {"albedo": [0.85, 0.60, 0.48], "d_mm": [1.0, 0.45, 0.25]},
    "marble_artist": {"albedo": [0.90, 0.88, 0.85], "d_mm": [2.5, 2.2, 1.9]},
    "jade": {"albedo": [0.55, 0.80, 0.60], "d_mm": [3.0, 4.5, 3.2]},
    "wax": {"albedo": [0.90, 0.75, 0.50], "d_mm": [4.0, 2.8, 1.6]},
    "milk": {"albedo": [0.92, 0.90, 0.85], "d_mm": [1.8, 1.5, 1.1]},
}

# how the walk ends photons (part of the cache's provenance: runs before issue #18 dropped photons at the cap)
MC_TERMINATION = ("implicit capture and roulette for 100000 scatterings, analog absorption after; a non-absorbing "
                  "half-space's photon tallied as reflected at the cap")
MEASURED_ETA = 1.3  # Jensen et al. 2001, Table 2 caption: "index of refraction 1.3"
DEFAULT_PHOTONS = 100_000
SLAB_T_OVER_D = (0.25, 0.5, 1.0, 2.0, 4.0)  # slab thicknesses for the Monte Carlo transmission, in units of d
SLAB_PHOTONS_FRACTION = 5  # slab runs use photons / 5 each (five thicknesses per channel)
MEDIUM_SLAB_PHOTONS_FRACTION = 10  # the medium's transmittance table: photons / 10 per thickness
IMAGE_PX_PER_D = 2.0  # image-space errors: the widest channel's d spans 2 pixels (a face close-up at 1080p)


# ------------------------------------------------------------------------------------------------------------------
# sources
# ------------------------------------------------------------------------------------------------------------------


def measured_materials(path: str | os.PathLike | None = None) -> dict[str, dict[str, list[float]]]:
    """The measured coefficients (``sigma_s_prime``, ``sigma_a`` in 1/mm, (3,) each) by name; default: the copy of
    Jensen et al. 2001, Table 2 shipped in ``sss_jax/data``."""
    if path is None:
        text = resources.files("sss_jax").joinpath("data/measured_materials.csv").read_text()
        where = "sss_jax/data/measured_materials.csv"
    else:
        try:
            text = pathlib.Path(path).read_text()
        except OSError as exc:
            raise SSSInputError(f"{path}: cannot read measured materials ({exc.strerror})") from None
        where = str(path)
    rows = csv.DictReader(line for line in text.splitlines() if line.strip() and not line.startswith("#"))
    out = {}
    need = [f"{k}_{c}" for k in ("sigma_s_prime", "sigma_a") for c in "rgb"]
    for i, row in enumerate(rows, start=2):
        missing = [k for k in ["name", *need] if not row.get(k)]
        if missing:
            raise SSSInputError(f"{where}: row {i} lacks {', '.join(missing)}")
        try:
            vals = {k: float(row[k]) for k in need}
        except ValueError as exc:
            raise SSSInputError(f"{where}: row {i} ({row['name']}): {exc}") from None
        s = [vals[f"sigma_s_prime_{c}"] for c in "rgb"]
        a = [vals[f"sigma_a_{c}"] for c in "rgb"]
        if not all(math.isfinite(v) and v >= 0 for v in s + a) or not all(x + y > 0 for x, y in zip(s, a)):
            raise SSSInputError(f"{where}: row {i} ({row['name']}): coefficients must be finite, >= 0, "
                                f"with sigma_s' + sigma_a > 0 per channel; got sigma_s'={s}, sigma_a={a}")
        out[row["name"]] = {"sigma_s_prime": s, "sigma_a": a}
    return out


def material_names() -> list[str]:
    names = sorted(measured_materials()) + sorted(ARTIST_MATERIALS)
    assert len(set(names)) == len(names), "a preset name is both measured and artist"
    return names


def chandrasekhar_h(alpha: float, mu, *, nodes: int = 96, tol: float = 1e-13) -> np.ndarray:
    """Chandrasekhar's H-function for isotropic scattering with single-scattering albedo ``alpha``, at ``mu``.

    Iterates (damped) the form ``1/H(mu) = sqrt(1 - alpha) + (alpha/2) int_0^1 mu' H(mu') / (mu + mu') dmu'`` (Chandrasekhar
    1960, Eq. V.(40)), which converges for alpha = 1 as well, on Gauss-Legendre nodes, then evaluates it at ``mu``."""
    x, w = np.polynomial.legendre.leggauss(nodes)
    x, w = 0.5 * (x + 1), 0.5 * w
    root = math.sqrt(max(0.0, 1.0 - alpha))
    h = np.ones(nodes)
    for _ in range(100_000):
        # undamped, the iteration swings between two wrong curves near alpha = 1; averaged it settles
        new = 0.5 * h + 0.5 / (root + 0.5 * alpha * np.sum(w * x * h / (x[:, None] + x[None, :]), axis=1))
        if np.max(np.abs(new - h)) < tol:
            h = new
            break
        h = new
    mu = np.atleast_1d(np.asarray(mu, np.float64))
    return 1.0 / (root + 0.5 * alpha * np.sum(w * x * h / (mu[:, None] + x[None, :]), axis=1))


def albedo_from_surface_albedo(A: float) -> float:
    """Single-scattering albedo of the index-matched isotropic half-space whose pencil-beam total reflectance is
    ``A`` (bisection on ``A(alpha) = 1 - H(1) sqrt(1 - alpha)``, which rises monotonically from 0 to 1)."""
    if not (0.0 <= A < 1.0):
        raise ValueError(f"surface albedo must lie in [0, 1), got {A}")
    lo, hi = 0.0, 1.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if 1.0 - chandrasekhar_h(mid, 1.0)[0] * math.sqrt(1.0 - mid) < A:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def material_source(name: str, *, measured_csv: str | os.PathLike | None = None,
                    artist: dict[str, Any] | None = None) -> dict[str, Any]:
    """The ``source`` block of a preset: where the material comes from, its parameters and units, and the medium
    (single-scattering albedo per channel, mean free path in mm, boundary eta) the Monte Carlo reference walks."""
    if artist is not None or name in ARTIST_MATERIALS:
        spec = artist if artist is not None else ARTIST_MATERIALS[name]
        A = np.asarray(spec["albedo"], np.float64)
        d = np.asarray(spec["d_mm"], np.float64)
        if A.shape != (3,) or not np.all((A >= 0) & (A < 1)):
            raise SSSInputError(f"{name}: albedo must be 3 values in [0, 1), got {A.tolist()}")
        if d.shape != (3,) or not np.all(np.isfinite(d) & (d > 0)):
            raise SSSInputError(f"{name}: d_mm must be 3 finite values > 0, got {d.tolist()}")
        alpha = [albedo_from_surface_albedo(float(a)) for a in A]
        mfp = (d * np.asarray(scaling_searchlight(A))).tolist()
        return {"kind": "artist", "albedo": A.tolist(), "d_mm": d.tolist(), "units": {"albedo": "1", "d_mm": "mm"},
                "medium": {"single_scattering_albedo": alpha, "mean_free_path_mm": mfp, "eta": 1.0, "phase": "isotropic",
                           "derivation": "alpha from A = 1 - H(1) sqrt(1 - alpha) (Chandrasekhar, index-matched, "
                                         "isotropic); mean free path = d s(A), searchlight s(A) = 1.85 - A + 7|A - 0.8|^3"}}
    table = measured_materials(measured_csv)
    if name not in table:
        raise SSSInputError(f"unknown material {name!r}; measured: {', '.join(sorted(table))}; artist: "
                            f"{', '.join(sorted(ARTIST_MATERIALS))}")
    s = np.asarray(table[name]["sigma_s_prime"])
    a = np.asarray(table[name]["sigma_a"])
    st = s + a
    return {"kind": "measured", "reference": "Jensen, Marschner, Levoy, Hanrahan 2001, A Practical Model for "
            "Subsurface Light Transport, Table 2", "sigma_s_prime_per_mm": s.tolist(), "sigma_a_per_mm": a.tolist(),
            "units": {"sigma_s_prime_per_mm": "1/mm", "sigma_a_per_mm": "1/mm"},
            "medium": {"single_scattering_albedo": (s / st).tolist(), "mean_free_path_mm": (1 / st).tolist(),
                       "eta": MEASURED_ETA, "phase": "isotropic (reduced coefficients)",
                       "derivation": "alpha' = sigma_s'/(sigma_s' + sigma_a), mean free path = 1/(sigma_s' + sigma_a); "
                                     "A = Monte Carlo total diffuse reflectance (pencil beam, eta 1.3); "
                                     "d = mean free path / s(A), searchlight s(A) = 1.85 - A + 7|A - 0.8|^3"}}


# ------------------------------------------------------------------------------------------------------------------
# Monte Carlo references (cached with their provenance)
# ------------------------------------------------------------------------------------------------------------------


def _r_max_mfp(alpha: float) -> float:
    """Profile range in mean free paths: 25/s(A) holds > 99.9% of a Burley profile (its CCDF at 20 d is 1e-3),
    with A bounded above by the index-matched reflectance of the medium."""
    A = 1.0 - chandrasekhar_h(alpha, 1.0)[0] * math.sqrt(1.0 - alpha)
    return float(min(30.0, max(3.0, 25.0 / float(scaling_searchlight(A)))))


def _provenance(medium: dict, photons: int, seed: int) -> dict[str, Any]:
    return {"photons": int(photons), "seed": int(seed), "version": __version__, "eta": medium["eta"],
            "single_scattering_albedo": medium["single_scattering_albedo"], "incidence": "pencil", "g": 0.0,
            "termination": MC_TERMINATION}


def _slab_provenance(photons: int, seed: int, d_mm: np.ndarray) -> dict[str, Any]:
    return {"t_over_d": list(SLAB_T_OVER_D), "photons": int(photons) // SLAB_PHOTONS_FRACTION, "seed": int(seed),
            "d_mm": [float(v) for v in d_mm], "termination": MC_TERMINATION}


def _same(a: Any, b: Any, rel_tol: float = 1e-12) -> bool:
    """Provenances match: equal, floats to ``rel_tol`` (a derived albedo may differ in its last bits across CPUs)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k], rel_tol) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y, rel_tol) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        return isinstance(a, (int, float)) and isinstance(b, (int, float)) and math.isclose(a, b, rel_tol=rel_tol)
    return a == b


# The slabs' d is a fitted value: the least-squares solver returns it to ~1e-9 relative, and its last digits move
# with the machine and the library versions. Slabs run for a d within this of the current fit are the same experiment.
_SLAB_D_REL_TOL = 1e-7


def _read_cache(path: pathlib.Path | None, log: Callable[[str], None]) -> dict | None:
    if path is None or not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except ValueError as exc:
        log(f"  {path}: unreadable cache ({exc}), simulating again")
        return None


def montecarlo_profiles(name: str, medium: dict, *, photons: int, seed: int, cache_dir: pathlib.Path | None,
                        log: Callable[[str], None]) -> tuple[list[MCResult], dict]:
    """Semi-infinite reflectance profiles per channel (pencil beam), from ``cache_dir/<name>.json`` when its
    provenance (photons, seed, version, medium) matches, else simulated and cached."""
    prov = _provenance(medium, photons, seed)
    path = cache_dir / f"{name}.json" if cache_dir is not None else None
    cached = _read_cache(path, log)
    if cached is not None and _uncapped_before_termination(cached, prov):
        # a run from before the termination was recorded in which no photon reached the cap: the new walk makes
        # the same decisions from the same random numbers (checked on apple: equal tallies and event counts), so it
        # is this run; the cache is rewritten with the full provenance
        cached["provenance"] = prov
        if path is not None:
            write_bytes_atomic(path, (json.dumps(cached, indent=1) + "\n").encode())
    if cached is not None:
        if _same(cached.get("provenance"), prov):
            try:
                return [MCResult.from_json(c) for c in cached["profiles"]], prov
            except (KeyError, TypeError, ValueError) as exc:
                log(f"  {path}: unreadable cache ({exc}), simulating again")
        else:
            log(f"  {path}: provenance differs from this run's, simulating again")
    eta = medium["eta"]
    profiles = []
    for c, alpha in enumerate(medium["single_scattering_albedo"]):
        log(f"  Monte Carlo {name} channel {'RGB'[c]}: albedo {alpha:.6f}, eta {eta}, {photons} photons")
        profiles.append(simulate(alpha, photons=photons, eta=eta, seed=seed + c, r_max_mfp=_r_max_mfp(alpha),
                                 bins=200))
    if path is not None:
        data = {"name": name, "provenance": prov, "mean_free_path_mm": medium["mean_free_path_mm"],
                "profiles": [p.to_json() for p in profiles]}
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(path, (json.dumps(data, indent=1) + "\n").encode())
    return profiles, prov


def _uncapped_before_termination(cached: dict, prov: dict) -> bool:
    """A cached profile run whose provenance lacks only ``termination`` and in which no photon was capped."""
    old = cached.get("provenance")
    if not isinstance(old, dict) or "termination" in old:
        return False
    try:
        uncapped = all(p["capped_photons"] == 0 and p["capped_weight"] == 0.0 for p in cached["profiles"])
    except (KeyError, TypeError):
        return False
    return uncapped and _same(old, {k: v for k, v in prov.items() if k != "termination"})


def montecarlo_slabs(name: str, medium: dict, d_mm: np.ndarray, *, photons: int, seed: int,
                     cache_dir: pathlib.Path | None, log: Callable[[str], None]) -> dict[str, Any]:
    """Total transmittance (normal pencil beam) of slabs ``SLAB_T_OVER_D`` times d thick, per channel, cached beside
    the profiles with its own provenance (the d it was run for included)."""
    prov = _slab_provenance(photons, seed, d_mm)
    path = cache_dir / f"{name}.json" if cache_dir is not None else None
    cached = _read_cache(path, log)
    if cached is not None and isinstance(cached.get("slab"), dict):
        old = cached["slab"].get("provenance")
        if isinstance(old, dict) and "termination" not in old and \
                _same(old, {k: v for k, v in prov.items() if k != "termination"}, _SLAB_D_REL_TOL):
            # slabs at most 4 d (about 5 mean free paths) thick: their walks end long before the cap, so a run from
            # before the termination was recorded is this run (apple's: equal transmittances)
            cached["slab"]["provenance"] = prov
            if path is not None:
                write_bytes_atomic(path, (json.dumps(cached, indent=1) + "\n").encode())
        if _same(cached["slab"].get("provenance"), prov, _SLAB_D_REL_TOL):
            return cached["slab"]
    eta = medium["eta"]
    mfp = np.asarray(medium["mean_free_path_mm"])
    slab: dict[str, Any] = {"provenance": prov, "thickness_mm": [], "T": [], "T_stderr": []}
    log(f"  Monte Carlo {name}: slabs t/d = {', '.join(f'{k:g}' for k in SLAB_T_OVER_D)}, {prov['photons']} photons")
    for c, alpha in enumerate(medium["single_scattering_albedo"]):
        t_mm = [float(k * d_mm[c]) for k in SLAB_T_OVER_D]
        runs = [simulate(alpha, photons=prov["photons"], eta=eta, slab_mfp=t / float(mfp[c]),
                         seed=seed + 100 * (c + 1) + i, bins=8, r_max_mfp=1.0) for i, t in enumerate(t_mm)]
        slab["thickness_mm"].append(t_mm)
        slab["T"].append([r.total_transmittance for r in runs])
        slab["T_stderr"].append([r.total_transmittance_stderr for r in runs])
    if path is not None and cached is not None:
        cached["slab"] = slab
        write_bytes_atomic(path, (json.dumps(cached, indent=1) + "\n").encode())
    return slab


def montecarlo_medium_slabs(name: str, medium: dict, *, photons: int, seed: int, cache_dir: pathlib.Path | None,
                            log: Callable[[str], None]) -> dict[str, Any]:
    """The slab transmittance table of the preset's own medium (``_slab.medium_slab_table``: its reduced
    coefficients, its eta on both faces), cached beside the profiles under ``medium_slab`` with its provenance."""
    from ._slab import MEDIUM_TAU_NODES, medium_slab_table

    alpha = np.asarray(medium["single_scattering_albedo"], np.float64)
    sigma_t = 1.0 / np.asarray(medium["mean_free_path_mm"], np.float64)
    prov = {"photons": int(photons) // MEDIUM_SLAB_PHOTONS_FRACTION, "seed": int(seed), "eta": medium["eta"],
            "single_scattering_albedo": alpha.tolist(), "mean_free_path_mm": medium["mean_free_path_mm"],
            "tau_nodes": list(MEDIUM_TAU_NODES), "termination": MC_TERMINATION}
    path = cache_dir / f"{name}.json" if cache_dir is not None else None
    cached = _read_cache(path, log)
    if (cached is not None and isinstance(cached.get("medium_slab"), dict)
            and _same(cached["medium_slab"].get("provenance"), prov)):
        return cached["medium_slab"]
    log(f"  Monte Carlo {name}: slabs of its medium (eta {medium['eta']}), {len(MEDIUM_TAU_NODES)} thicknesses per "
        f"channel, {prov['photons']} photons each")
    table = medium_slab_table(alpha * sigma_t, (1 - alpha) * sigma_t, float(medium["eta"]), photons=prov["photons"],
                              seed=seed + 7000)
    table["provenance"] = prov
    if path is not None and cached is not None:
        cached["medium_slab"] = table
        write_bytes_atomic(path, (json.dumps(cached, indent=1) + "\n").encode())
    return table


def _burley_residual(x, data):
    """``r (R_burley(r; d) - R_mc(r)) / ||r R_mc||`` on the Monte Carlo bins, unit-energy profiles."""
    r, R_mc, norm = data
    return r * (burley_R(r, x[0]) - R_mc) / norm


def fit_burley_d(result: MCResult, mfp_mm: float, d0_mm: float, *, solver: str = "optimistix") -> dict[str, Any]:
    """Burley's d (mm) closest to a Monte Carlo profile: least squares on ``r R(r)`` of the unit-energy profiles over
    the run's bins, from ``d0`` (the searchlight ``mfp / s(A)``), within [d0/20, 20 d0]."""
    from ._fitting import _solve

    r = result.r_mfp * mfp_mm
    R_mc = result.R / (mfp_mm**2) / max(result.total_reflectance, 1e-300)
    data = (jnp.asarray(r), jnp.asarray(R_mc), jnp.asarray(float(np.linalg.norm(r * R_mc))))
    t0 = time.perf_counter()
    x, outcome, it = _solve(_burley_residual, np.array([d0_mm]), np.array([d0_mm / 20]), np.array([d0_mm * 20]),
                            solver, args=data)
    err = float(jnp.linalg.norm(_burley_residual(jnp.asarray(x), data)))
    return {"d_mm": float(x[0]), "outcome": outcome, "iterations": it, "seconds": time.perf_counter() - t0,
            "error_relative_l2": err}


# ------------------------------------------------------------------------------------------------------------------
# errors
# ------------------------------------------------------------------------------------------------------------------


def _burley_vs_mc(res: MCResult, mfp_mm: float, d_mm: float) -> float:
    """``||r (R_burley - R_mc)|| / ||r R_mc||`` on the run's bins, both profiles of unit energy."""
    r = res.r_mfp * mfp_mm
    R_mc = res.R / (mfp_mm**2) / max(res.total_reflectance, 1e-300)
    return rel_l2(r * np.asarray(burley_R(r, d_mm)), r * R_mc)


def _radial_two_gaussian(tg: dict, r_mm: np.ndarray, angles: int = 64) -> np.ndarray:
    """Azimuthal average of the separable kernel ``a_m(x) a_m(y)`` at radii ``r_mm``, ``(N, 3)`` (1/mm^2): what the
    two passes spread around a point, as a radial profile comparable with R(r)."""
    th = (np.arange(angles) + 0.5) * (2 * np.pi / angles)
    x = r_mm[:, None] * np.cos(th)[None, :]
    y = r_mm[:, None] * np.sin(th)[None, :]
    def g(v, s):
        return np.exp(-0.5 * (v / s) ** 2) / (s * math.sqrt(2 * math.pi))

    out = []
    for c in range(3):
        w, sn, sf = tg["w"][c], tg["sigma_near_mm"][c], tg["sigma_far_mm"][c]
        ax = w * g(x, sn) + (1 - w) * g(x, sf)
        ay = w * g(y, sn) + (1 - w) * g(y, sf)
        out.append((ax * ay).mean(axis=1))
    return np.stack(out, axis=-1)


def profile_errors(d_mm: np.ndarray, mc: list[MCResult], mfp_mm: np.ndarray, tg_burley: dict,
                   tg_mc: dict) -> dict[str, Any]:
    """1D radial errors on the Monte Carlo bins: ``||r (R_model - R_mc)|| / ||r R_mc||`` per channel, every profile
    normalised to unit energy (the albedo is a separate factor), over r < the profile range of the run."""
    out: dict[str, list[float]] = {"burley_vs_montecarlo": [], "two_gaussian_vs_montecarlo": [],
                                   "two_gaussian_vs_burley": [], "two_gaussian_montecarlo_vs_montecarlo": []}
    for c, res in enumerate(mc):
        r = res.r_mfp * mfp_mm[c]
        R_mc = res.R / (mfp_mm[c] ** 2) / max(res.total_reflectance, 1e-300)
        R_b = np.asarray(burley_R(r, float(d_mm[c])))
        R_tg = _radial_two_gaussian(tg_burley, r)[:, c]
        R_tgm = _radial_two_gaussian(tg_mc, r)[:, c]
        out["burley_vs_montecarlo"].append(_burley_vs_mc(res, float(mfp_mm[c]), float(d_mm[c])))
        out["two_gaussian_vs_montecarlo"].append(rel_l2(r * R_tg, r * R_mc))
        out["two_gaussian_vs_burley"].append(rel_l2(r * R_tg, r * R_b))
        out["two_gaussian_montecarlo_vs_montecarlo"].append(rel_l2(r * R_tgm, r * R_mc))
    return out


def kernel_errors(d_mm: np.ndarray, mc_profile, tg_burley: dict, tg_mc: dict) -> dict[str, Any]:
    """Each two-Gaussian kernel as ``separable`` renders it (the product ``a(x) a(y)``) and as the radial mix, against
    the Burley and the Monte Carlo profile on pixels of side d per channel (the fit's objective) and of side d/2."""
    burley = BurleyProfile(jnp.asarray(d_mm, jnp.float64))
    out: dict[str, Any] = {
        "metric": "relative L2 per channel of the kernel against the profile, both integrated over the pixels of a "
                  f"{2 * RENDERED_HALF_PX + 1}^2 grid of side pixel_side_over_d x that channel's Burley d; "
                  "rendered_product: a(x) a(y), what separable renders; radial_mix: w G_near(r) + (1 - w) G_far(r)",
        "grid_half_px": RENDERED_HALF_PX,
    }
    for key, scale in (("pixel_d", RENDERED_PIXEL_PER_D), ("pixel_half_d", 0.5 * RENDERED_PIXEL_PER_D)):
        pix = scale * np.asarray(d_mm, np.float64)
        out[key] = {"pixel_side_over_d": scale,
                    "two_gaussian_vs_burley": rendered_kernel_errors(tg_burley, burley, pix),
                    "two_gaussian_vs_montecarlo": rendered_kernel_errors(tg_burley, mc_profile, pix),
                    "two_gaussian_montecarlo_vs_montecarlo": rendered_kernel_errors(tg_mc, mc_profile, pix)}
    return out


def image_errors(albedo, d_mm: np.ndarray, mc_profile, tg_burley: dict, tg_mc: dict, *, taps: int = 25,
                 size: int = 32) -> dict[str, Any]:
    """Image-space relative L2 of ``separable`` (two-Gaussian, ``taps`` per pass) and of ``burley`` against
    ``reference`` with the Burley profile and with the Monte Carlo profile, over the fitting's five test patterns,
    at a scale where the widest channel's d spans ``IMAGE_PX_PER_D`` pixels."""
    px_per_mm = IMAGE_PX_PER_D / float(np.max(d_mm))
    cam = Camera(focal_px=10.0 * px_per_mm, mm_per_unit=1.0)  # the patterns lie at depth 10 units
    patterns = image_patterns(size)
    ones = jnp.ones(3, jnp.float64)
    burley_mat = BurleyMaterial(ones, jnp.asarray(d_mm))
    mc_mat = ProfileMaterial(mc_profile, albedo=ones)
    # one window for every material (one compilation): 20 d of the widest channel holds 99.9% of a Burley profile
    # (its CCDF (e^{-20} + 3 e^{-20/3})/4 = 1e-3)
    radius = math.ceil(20 * IMAGE_PX_PER_D)
    ref_b = [np.asarray(reference(b, burley_mat, cam, radius_px=radius)) for b in patterns]
    ref_mc = [np.asarray(reference(b, mc_mat, cam, radius_px=radius)) for b in patterns]
    mat = lambda tg: TwoGaussianMaterial(ones, tg["w"], tg["sigma_near_mm"], tg["sigma_far_mm"])
    ref_b_on_mc = math.sqrt(sum(np.sum((a - b) ** 2) for a, b in zip(ref_b, ref_mc)) / sum(np.sum(b**2) for b in ref_mc))
    return {
        "metric": f"image-space relative L2 over the five test patterns ({size}x{size}), widest d = "
                  f"{IMAGE_PX_PER_D:g} px, {taps}-tap separable passes, against reference (dense convolution)",
        "px_per_mm": px_per_mm,
        "two_gaussian_vs_burley": image_error(mat(tg_burley), burley_mat, cam, patterns, taps=taps, references=ref_b),
        "two_gaussian_vs_montecarlo": image_error(mat(tg_burley), mc_mat, cam, patterns, taps=taps, references=ref_mc),
        "two_gaussian_montecarlo_vs_montecarlo": image_error(mat(tg_mc), mc_mat, cam, patterns, taps=taps,
                                                             references=ref_mc),
        "burley_reference_vs_montecarlo": ref_b_on_mc,
        # no scattering at all (local shading), for scale: what the cheap models are there to remove
        "local_shading_vs_burley": math.sqrt(sum(np.sum((np.asarray(b.irradiance) - r) ** 2)
                                                 for b, r in zip(patterns, ref_b)) / sum(np.sum(r**2) for r in ref_b)),
    }


def sta_errors(sta: dict, d_mm: np.ndarray, slab: dict) -> dict[str, Any]:
    """STA at normal light and view against the Monte Carlo slab transmittance and against Burley's
    ``(e^{-t/d} + 3 e^{-t/3d})/4`` at the Monte Carlo thicknesses; and that Burley slab model against Monte Carlo."""
    params = STAParams(**{k: sta[k] for k in ("distortion", "power", "scale", "ambient", "thickness_mm")},
                       dtype=jnp.float64)
    sta_vals, burley_vals, mc_vals = [], [], []
    for c in range(3):
        t = np.asarray(slab["thickness_mm"][c])
        sta_vals.append(np.asarray(sta_slab_response(params, jnp.asarray(t), jnp.asarray([0.0, 0.0, 1.0]),
                                                     jnp.asarray([0.0, 0.0, -1.0])))[:, c])
        burley_vals.append(np.asarray(burley_slab_transmittance(t, d_mm))[:, c])
        mc_vals.append(np.asarray(slab["T"][c]))
    sta_v, b_v, mc_v = (np.concatenate(v) for v in (sta_vals, burley_vals, mc_vals))
    return {"metric": "relative L2 of slab transmittance at normal light and view, thicknesses "
                      f"t/d = {', '.join(f'{k:g}' for k in SLAB_T_OVER_D)} per channel",
            "sta_vs_burley": rel_l2(sta_v, b_v), "sta_vs_montecarlo": rel_l2(sta_v, mc_v),
            "burley_vs_montecarlo": rel_l2(b_v, mc_v)}


def transmission_curves(preset: dict, slab: dict, *, points: int = 60) -> dict[str, Any]:
    """A preset's slab transmittance at normal light and view from its fitted STA, the closed-form thin model and the
    tabulated slab model, against its cached Monte Carlo ``slab`` block: the values at the Monte Carlo thicknesses,
    their relative L2 over all channels, and fine curves over t/d for plots."""
    from ._slab import slab_transmittance

    sta = preset["sta"]
    f64 = jax.dtypes.canonicalize_dtype(jnp.float64)  # float32 unless x64 is on (the preset script turns it on)
    params = STAParams(**{k: sta[k] for k in ("distortion", "power", "scale", "ambient", "thickness_mm")}, dtype=f64)
    albedo = np.asarray(preset["albedo"], np.float64)
    d = np.asarray(preset["burley"]["d_mm"], np.float64)
    light, view = jnp.asarray([0.0, 0.0, 1.0]), jnp.asarray([0.0, 0.0, -1.0])

    def models(t_mm: np.ndarray, c: int) -> dict[str, np.ndarray]:
        t = jnp.asarray(t_mm, f64)
        return {"sta": np.asarray(sta_slab_response(params, t, light, view))[:, c],
                "thin": np.asarray(burley_slab_transmittance(t, d))[:, c],
                "slab": np.asarray(slab_transmittance(t, albedo[c], d[c]))}

    at_mc = {m: [] for m in ("sta", "thin", "slab")}
    fine_t_over_d = np.geomspace(0.1, 5.0, points)
    fine = {m: [] for m in at_mc}
    for c in range(3):
        for m, v in models(np.asarray(slab["thickness_mm"][c], np.float64), c).items():
            at_mc[m].append(v)
        for m, v in models(fine_t_over_d * d[c], c).items():
            fine[m].append(v.tolist())
    mc = np.concatenate([np.asarray(v, np.float64) for v in slab["T"]])
    return {"t_over_d": [(np.asarray(t) / d[c]).tolist() for c, t in enumerate(slab["thickness_mm"])],
            "montecarlo": slab["T"], "montecarlo_stderr": slab["T_stderr"],
            "models": {m: [v.tolist() for v in vals] for m, vals in at_mc.items()},
            "rel_l2": {m: rel_l2(np.concatenate(vals), mc) for m, vals in at_mc.items()},
            "fine_t_over_d": fine_t_over_d.tolist(), "fine": fine}


def engine_errors(albedo, d_mm: np.ndarray, mc_profile, mc_albedo) -> dict[str, Any]:
    """What each engine renders for the preset (``engines.engine_marginals``: its kernel as that engine builds it)
    against the Burley profile and against the Monte Carlo profile, as 1D-marginal bin masses (bins of d/4 out to
    20 d plus both tails): relative L2 and the fraction of the reference's diffuse reflectance the engine loses."""
    from .engines._common import masses_from_cdf as _masses_from_cdf
    from .engines import engine_errors_against, engine_marginals

    marg = engine_marginals(albedo, d_mm)
    edges = marg["edges"]
    cdf = np.stack([np.asarray(marginal_cdf(mc_profile, jnp.asarray(edges[c])))[:, c] for c in range(3)])
    m_mc = _masses_from_cdf(cdf)
    return {"metric": "1D marginal (one separable pass / the projection of a radial kernel) bin masses, bins d/4 "
                      "wide to 20 d plus tails: relative L2 per channel; energy_lost = 1 - A_engine sum(m_engine) / "
                      "(A_ref sum(m_ref))",
            "vs_burley": engine_errors_against(marg, marg["reference"], marg["albedo"]["reference"]),
            "vs_montecarlo": engine_errors_against(marg, m_mc, mc_albedo)}


# ------------------------------------------------------------------------------------------------------------------
# engine export
# ------------------------------------------------------------------------------------------------------------------


def export_taps(name: str, tg: dict, *, taps: int = 25) -> dict[str, Any]:
    """The two-Gaussian kernel as Jimenez's ``float4(weight_r, weight_g, weight_b, offset)`` taps, centre first,
    offsets in mm (multiply by the pixels per mm at the surface, as ``sssWidth`` does in the reference shader)."""
    k = two_gaussian_kernel(jnp.asarray(tg["w"]), jnp.asarray(tg["sigma_near_mm"]), jnp.asarray(tg["sigma_far_mm"]),
                            taps=taps)
    off = np.asarray(k.offsets_mm, np.float64)
    wts = np.asarray(k.weights, np.float64)
    ident = "".join(ch if ch.isalnum() else "_" for ch in name)
    rows = [f"{wts[i, 0]:.8f}, {wts[i, 1]:.8f}, {wts[i, 2]:.8f}, {off[i]:.8f}" for i in range(taps)]
    hlsl = (f"// sss_jax {__version__}: {name}, two-Gaussian kernel, {taps} taps (rgb weights, offset mm), centre first\n"
            f"static const float4 kernel_{ident}[{taps}] = {{\n" + ",\n".join(f"    float4({r})" for r in rows) + "\n};")
    glsl = (f"// sss_jax {__version__}: {name}, two-Gaussian kernel, {taps} taps (rgb weights, offset mm), centre first\n"
            f"const vec4 kernel_{ident}[{taps}] = vec4[{taps}](\n" + ",\n".join(f"    vec4({r})" for r in rows) + "\n);")
    return {"taps": taps, "layout": "float4(weight_r, weight_g, weight_b, offset_mm), centre tap first",
            "offsets_mm": off.tolist(), "weights": wts.tolist(), "hlsl": hlsl, "glsl": glsl}


# ------------------------------------------------------------------------------------------------------------------
# one preset, all presets
# ------------------------------------------------------------------------------------------------------------------


def _strip(fit_block: dict) -> tuple[dict, dict]:
    params = {k: v for k, v in fit_block.items() if k != "fit"}
    return params, fit_block["fit"]


def fit_preset(name: str, *, photons: int = DEFAULT_PHOTONS, seed: int = 0, solver: str = "optimistix",
               taps: int = 25, cache_dir: str | os.PathLike | None = None, measured_csv=None,
               artist: dict | None = None, log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Everything a preset holds, for a measured material, a built-in artist material, or ``artist`` =
    ``{"albedo": (3,), "d_mm": (3,)}`` under a new ``name``. Fits and errors run in float64."""
    with jax.enable_x64(True):
        return _fit_preset(name, photons=photons, seed=seed, solver=solver, taps=taps, cache_dir=cache_dir,
                           measured_csv=measured_csv, artist=artist, log=log)


def _fit_preset(name, *, photons, seed, solver, taps, cache_dir, measured_csv, artist, log) -> dict[str, Any]:
    from .engines import engine_blocks

    log = log or (lambda s: None)
    t_start = time.perf_counter()
    source = material_source(name, measured_csv=measured_csv, artist=artist)
    medium = source["medium"]
    mfp = np.asarray(medium["mean_free_path_mm"])

    cache = pathlib.Path(cache_dir) if cache_dir is not None else None
    profiles, prov = montecarlo_profiles(name, medium, photons=photons, seed=seed, cache_dir=cache, log=log)
    A_mc = np.asarray([p.total_reflectance for p in profiles])
    d_searchlight = mfp / np.asarray(scaling_searchlight(A_mc))
    burley_fit = None
    if source["kind"] == "artist":
        albedo, d = np.asarray(source["albedo"]), np.asarray(source["d_mm"])
    else:
        # the searchlight s(A) was fitted to index-matched media; with the eta 1.3 boundary internal reflection
        # widens the profile, so the d that best matches the transport is fitted to it, from mfp / s(A)
        albedo = A_mc
        fits = [fit_burley_d(p, float(m), float(d0), solver=solver) for p, m, d0 in zip(profiles, mfp, d_searchlight)]
        d = np.asarray([f["d_mm"] for f in fits])
        burley_fit = {"solver": solver, "objective": "1D radial ||r (R_burley(d) - R_mc)|| / ||r R_mc||, unit-energy "
                      "profiles, from d = mfp / s_searchlight(A)",
                      "outcome": "successful" if all(f["outcome"] == "successful" for f in fits) else
                      ";".join(f["outcome"] for f in fits),
                      "iterations": [f["iterations"] for f in fits],
                      "seconds": round(sum(f["seconds"] for f in fits), 3),
                      "error_relative_l2": [f["error_relative_l2"] for f in fits],
                      "error_relative_l2_searchlight": [_burley_vs_mc(p, float(m), float(d0))
                                                        for p, m, d0 in zip(profiles, mfp, d_searchlight)]}
    slab = montecarlo_slabs(name, medium, d, photons=photons, seed=seed, cache_dir=cache, log=log)
    medium_slab = montecarlo_medium_slabs(name, medium, photons=photons, seed=seed, cache_dir=cache, log=log)
    mc = {"profiles": profiles, "slab": slab, "provenance": {**prov, "slab": slab["provenance"]}}
    mc_profile = to_tabulated_profile(profiles, mfp.tolist())

    log(f"  fitting {name}: two-Gaussian to Burley and to Monte Carlo, STA to slab transmission ({solver})")
    tg_b, fit_tg_b = _strip(fit_two_gaussian_to_burley(d, solver=solver))
    tg_m, fit_tg_m = _strip(fit_two_gaussian_profile(mc_profile, pixel_mm=RENDERED_PIXEL_PER_D * d, solver=solver))
    sta, fit_sta_rec = _strip(fit_sta(d, solver=solver))

    errors = {
        "profile": {"metric": "1D radial ||r (R_model - R_ref)|| / ||r R_ref|| on the Monte Carlo bins, profiles of "
                              "unit energy; two-Gaussian as the azimuthal average of a_m(x) a_m(y)", "per_channel": True,
                    **profile_errors(d, mc["profiles"], mfp, tg_b, tg_m),
                    "two_gaussian_fit_objective": fit_tg_b["error_relative_l2"]},
        "kernel": kernel_errors(d, mc_profile, tg_b, tg_m),
        "image": image_errors(albedo, d, mc_profile, tg_b, tg_m, taps=taps),
        "sta": {**sta_errors(sta, d, mc["slab"]), "fit_objective": fit_sta_rec["error_relative_l2"]},
        "engines": engine_errors(albedo, d, mc_profile, A_mc),
        "albedo": {"metric": "Monte Carlo total diffuse reflectance (pencil beam) against the preset's albedo A",
                   "montecarlo": A_mc.tolist(),
                   "montecarlo_stderr": [p.total_reflectance_stderr for p in mc["profiles"]],
                   "capped_weight": [p.capped_weight for p in mc["profiles"]]},
    }
    preset = {
        "name": name,
        "source": source,
        "albedo": albedo.tolist(),
        "burley": {"d_mm": d.tolist(), "d_searchlight_mm": d_searchlight.tolist(), "mean_free_path_mm": mfp.tolist(),
                   "d_rule": "artist's d" if burley_fit is None else
                   "fitted to the Monte Carlo profile (r R(r) least squares) from mfp / s_searchlight(A)"},
        "separable": {"two_gaussian": tg_b, "two_gaussian_montecarlo": tg_m, "export": export_taps(name, tg_b, taps=taps)},
        "sta": sta,
        "transmittance": {
            "model": "total transmittance (unscattered + scattered) of a slab of the preset's medium (source.medium: "
                     "isotropic with the reduced coefficients, its eta on both faces) under a normal back light, by "
                     "the Monte Carlo walk; thickness_mm per channel (tau_nodes mean free paths, and 0); "
                     "translucency(model='slab') interpolates log T linearly in t",
            **{k: medium_slab[k] for k in ("eta", "tau_nodes", "thickness_mm", "T", "T_stderr", "resolved")},
            "photons": medium_slab["provenance"]["photons"]},
        "errors": errors,
        "fit": {**({"burley": burley_fit} if burley_fit else {}), "two_gaussian": fit_tg_b, "two_gaussian_montecarlo": fit_tg_m, "sta": fit_sta_rec,
                "solver": solver, "seconds": round(time.perf_counter() - t_start, 3)},
        "montecarlo": {**mc["provenance"], "cache": f"montecarlo/{name}.json"},
        "engines": engine_blocks(albedo, d),
        "version": __version__,
    }
    return preset


def _json_bytes(data: Any) -> bytes:
    return (json.dumps(data, indent=2) + "\n").encode()


def fit_presets(names: Iterable[str] | None = None, *, out_dir: str | os.PathLike = "fits",
                photons: int = DEFAULT_PHOTONS, seed: int = 0, solver: str = "optimistix", taps: int = 25,
                plots: bool = True, readme: bool = True, measured_csv=None,
                artist: dict[str, dict] | None = None, log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Fit and write ``out_dir/<name>.json`` for each material (default: all measured and artist materials) and the
    schema, plots and README; a material that fails is reported and the others go on. Returns
    ``{"written": [paths], "failed": {name: message}}``."""
    log = log or (lambda s: print(s, file=sys.stderr, flush=True))
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    artist = dict(artist or {})
    todo = list(names) if names is not None else (sorted(measured_materials(measured_csv)) + sorted(ARTIST_MATERIALS))
    todo += [n for n in artist if n not in todo]
    known = set(measured_materials(measured_csv)) | set(ARTIST_MATERIALS) | set(artist)
    written, failed = [], {}
    for i, name in enumerate(todo, 1):
        log(f"[{i}/{len(todo)}] {name}")
        if name not in known:
            failed[name] = f"unknown material {name!r}; known: {', '.join(sorted(known))}"
            log(f"  failed: {failed[name]}")
            continue
        try:
            preset = fit_preset(name, photons=photons, seed=seed, solver=solver, taps=taps,
                                cache_dir=out / "montecarlo", measured_csv=measured_csv, artist=artist.get(name),
                                log=log)
        except (SSSInputError, ValueError, FloatingPointError, RuntimeError) as exc:
            failed[name] = f"{type(exc).__name__}: {exc}"
            log(f"  failed: {failed[name]}")
            continue
        path = out / f"{name}.json"
        write_bytes_atomic(path, _json_bytes(preset))
        written.append(str(path))
        log(f"  wrote {path} ({preset['fit']['seconds']:.1f} s)")
        if plots:
            plot_preset(preset, out)
    schema = resources.files("sss_jax").joinpath("data/preset.schema.json").read_bytes()
    write_bytes_atomic(out / "schema.json", schema)
    if readme:
        write_presets_readme(out)
    return {"written": written, "failed": failed}


# ------------------------------------------------------------------------------------------------------------------
# pictures and the table
# ------------------------------------------------------------------------------------------------------------------


def plot_preset(preset: dict, out_dir: pathlib.Path) -> pathlib.Path:
    """``plots/<name>.png``: r R(r) per channel of Monte Carlo (with its standard error), Burley and the two
    fitted two-Gaussian kernels, in the manner of the paper's Fig. 4."""
    from matplotlib.figure import Figure

    name = preset["name"]
    cache = json.loads((out_dir / preset["montecarlo"]["cache"]).read_text())
    mfp = np.asarray(cache["mean_free_path_mm"])
    d = np.asarray(preset["burley"]["d_mm"])
    fig = Figure(figsize=(12, 3.6), layout="constrained")  # a Figure of its own: no global matplotlib state
    axes = fig.subplots(1, 3)
    for c, ax in enumerate(axes):
        prof = cache["profiles"][c]
        r = np.asarray(prof["profile"]["r_mfp"]) * mfp[c]
        A = prof["total_reflectance"]
        # r R(r) in 1/mm of a unit-energy profile: rR in the cache is per mean free path
        rR = np.asarray(prof["profile"]["rR"]) / mfp[c] / A
        err = np.asarray(prof["profile"]["rR_stderr"]) / mfp[c] / A
        ax.errorbar(r, rR, yerr=err, fmt=".", ms=2, color="0.3", elinewidth=0.6, label="Monte Carlo (±1 s.e.)")
        ax.plot(r, r * np.asarray(burley_R(r, float(d[c]))), color="C3", label=f"Burley d={d[c]:.3g} mm")
        ax.plot(r, r * _radial_two_gaussian(preset["separable"]["two_gaussian"], r)[:, c], color="C0",
                label="two-Gaussian (fit to Burley)")
        ax.plot(r, r * _radial_two_gaussian(preset["separable"]["two_gaussian_montecarlo"], r)[:, c], "--",
                color="C2", label="two-Gaussian (fit to MC)")
        ax.set_xlim(0, float(min(r[-1], 12 * d[c])))
        ax.set_title(f"{name}: {'RGB'[c]}  A={preset['albedo'][c]:.3f}")
        ax.set_xlabel("r (mm)")
        ax.set_ylabel("r R(r) (1/mm)")
    axes[0].legend(fontsize=7)
    path = out_dir / "plots" / f"{name}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, metadata={"Software": None})
    write_bytes_atomic(path, buf.getvalue())
    return path


def _triple_str(v, fmt="{:.3g}") -> str:
    return ", ".join(fmt.format(x) for x in v)


ENGINE_ORDER = ("cycles", "eevee", "hdrp", "unreal", "jimenez")


def load_presets(out_dir: str | os.PathLike) -> list[dict]:
    """Every preset file in ``out_dir`` (not the schema), by name."""
    return [json.loads(p.read_text()) for p in sorted(pathlib.Path(out_dir).glob("*.json")) if p.stem != "schema"]


def preset_rows(presets: list[dict]) -> list[dict[str, Any]]:
    """One summary row per preset: parameters and the errors of each cheap model against Burley and Monte Carlo."""
    rows = []
    for p in presets:
        e = p["errors"]
        rows.append({
            "preset": p["name"], "source": p["source"]["kind"], "albedo A": _triple_str(p["albedo"]),
            "d (mm)": _triple_str(p["burley"]["d_mm"]),
            "2G w": _triple_str(p["separable"]["two_gaussian"]["w"], "{:.2f}"),
            "2G sigma near / far (mm)": " / ".join(_triple_str(p["separable"]["two_gaussian"][k])
                                                  for k in ("sigma_near_mm", "sigma_far_mm")),
            "Burley vs MC": _triple_str(e["profile"]["burley_vs_montecarlo"], "{:.3f}"),
            "2G rendered / radial mix vs Burley": "{:.3f} / {:.3f}".format(
                max(e["kernel"]["pixel_d"]["two_gaussian_vs_burley"]["rendered_product"]),
                max(e["kernel"]["pixel_d"]["two_gaussian_vs_burley"]["radial_mix"])),
            "2G(MC) rendered vs MC": "{:.3f}".format(
                max(e["kernel"]["pixel_d"]["two_gaussian_montecarlo_vs_montecarlo"]["rendered_product"])),
            "2G image vs Burley": f"{e['image']['two_gaussian_vs_burley']:.3f}",
            "2G image vs MC": f"{e['image']['two_gaussian_vs_montecarlo']:.3f}",
            "medium slab T at 1 / 2 / 4 mm (R, G, B)": _medium_T_cell(p),
            "STA vs Burley slab": f"{e['sta']['sta_vs_burley']:.3f}",
            "STA vs MC slab": f"{e['sta']['sta_vs_montecarlo']:.3f}",
            "Burley slab vs MC slab": f"{e['sta']['burley_vs_montecarlo']:.3f}",
        })
    return rows


def _medium_T_cell(preset: dict) -> str:
    """The preset's medium transmittance (its ``transmittance`` table, as ``sss-jax transmit`` reads it) at 1, 2, 4 mm."""
    if "transmittance" not in preset:
        return "-"
    from ._materials import BurleyMaterial
    from ._slab import MediumMaterial

    medium = MediumMaterial.from_tables(BurleyMaterial(preset["albedo"], preset["burley"]["d_mm"]),
                                        [preset["transmittance"]])
    T = np.asarray(medium.transmittance(np.asarray([1.0, 2.0, 4.0])), np.float64)
    return " / ".join(_triple_str(row, "{:.2g}") for row in T)


def engine_rows(presets: list[dict]) -> list[dict[str, Any]]:
    """The engine table: per preset, each engine's kernel error (largest channel) against Burley and against Monte
    Carlo, the largest energy it loses against Monte Carlo, and the engine closest to Monte Carlo."""
    rows = []
    for p in presets:
        eng = p["errors"]["engines"]
        row: dict[str, Any] = {"preset": p["name"]}
        for name in ENGINE_ORDER:
            b = max(eng["vs_burley"][name]["error_relative_l2"])
            m = max(eng["vs_montecarlo"][name]["error_relative_l2"])
            lost = max(eng["vs_montecarlo"][name]["energy_lost"], key=abs)
            row[name] = f"{b:.3f} / {m:.3f} / {lost:+.3f}"
        row["closest to MC"] = min(ENGINE_ORDER, key=lambda n: max(eng["vs_montecarlo"][n]["error_relative_l2"]))
        rows.append(row)
    return rows


def _markdown_table(rows: list[dict[str, Any]]) -> list[str]:
    cols = list(rows[0]) if rows else []
    return (["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
            + ["| " + " | ".join(str(r[c]) for c in cols) + " |" for r in rows])


def write_presets_readme(out_dir: str | os.PathLike) -> pathlib.Path:
    """``README.md`` with a table of every preset in ``out_dir`` (its numbers read from the files)."""
    out = pathlib.Path(out_dir)
    presets = load_presets(out)
    lines = [
        "# Presets",
        "",
        "Written by `python scripts/fit_presets.py` (the same as `sss-jax fit --all`); re-running it reproduces every",
        "file here except the `seconds` fields. Each `<name>.json` validates against `schema.json`. Monte Carlo",
        "references are cached in `montecarlo/` with their provenance; `plots/<name>.png` shows r R(r) per channel",
        "(Monte Carlo with its standard error, Burley, and the two fitted two-Gaussian kernels), as in Fig. 4 of the",
        "paper.",
        "",
        "**Derivation.** Measured materials (Jensen et al. 2001, Table 2, eta 1.3): mean free path 1/(sigma_s' +",
        "sigma_a), single-scattering albedo sigma_s'/(sigma_s' + sigma_a), surface albedo A = Monte Carlo total diffuse",
        "reflectance (pencil beam, eta 1.3), d = mean free path / s(A) with the searchlight s(A) = 1.85 - A +",
        "7|A - 0.8|^3. Artist materials (A, d as an artist sets them): the index-matched isotropic medium whose",
        "reflectance is A (Chandrasekhar's 1 - H(1) sqrt(1 - alpha), inverted), mean free path d s(A).",
        "",
        "**Two-Gaussian kernels** are fitted as `separable` renders them: the product a(x) a(y) of the 1D kernel",
        "a(x) = w N(x; sigma_near) + (1 - w) N(x; sigma_far), integrated over pixels of side d (each channel's Burley",
        "d; the pixel spans +-d/2), against the target profile integrated over the same pixels, on 41x41 pixels",
        "(unweighted relative L2), once to Burley and once to the Monte Carlo profile.",
        "",
        "**Errors** (per channel, R/G/B). *Burley vs MC*: 1D radial relative L2 of r R(r), unit-energy profiles.",
        "*2G rendered / radial mix vs Burley*: the fitted kernel's product a(x) a(y) (what the pass renders) and its",
        "radial mix w G_near(r) + (1 - w) G_far(r), against Burley on pixels of side d (largest channel; errors",
        "on pixels of side d/2 are in the files). *2G(MC) rendered vs MC*: the kernel fitted to Monte Carlo, rendered.",
        "*2G image*: image-space relative L2 of the 25-tap two-Gaussian `separable` against `reference` over the five",
        "test patterns with the widest d spanning 2 px (vs the Burley profile / vs the Monte Carlo profile).",
        "*STA*: relative L2 of slab transmittance, STA (fitted to Burley's slab model) vs Monte Carlo slabs at",
        "t/d = 0.25 ... 4.",
        "",
        "**Medium slab T** (the `transmittance` block): the fraction of a normally incident back light that leaves",
        "the front face of a slab of the preset's own medium (its reduced coefficients; eta 1.3 on both faces for the",
        "measured materials, index-matched for the artist ones), unscattered and scattered light together, by the Monte",
        "Carlo walk at 0.1 ... 16 mean free paths per channel, interpolated (log T linear in t). All absorption is in",
        "it: `translucency(model=\"slab\")` adds light x T x cos with no albedo factor; `sss-jax transmit --preset NAME",
        "--thickness-mm 1,2,4` prints it. skin1 agrees with Prahl's adding-doubling (iadpython) within 2% at 1, 2, 4 mm",
        "in every channel above 0.01 (tests/test_slab_transmission.py; blue at 4 mm, 0.0086 against 0.0080, is 7% off).",
        "",
    ]
    lines += _markdown_table([dict(r, plot=f"[png](plots/{r['preset']}.png)") for r in preset_rows(presets)])
    lines += [
        "",
        "## What each engine renders",
        "",
        "Each preset's material converted to every engine (the `engines` block) and that engine's kernel as it builds",
        "it (Cycles: Burley truncated at 16 d; EEVEE legacy: its precomputed kernel; HDRP: Burley cut at its filter",
        "radius; UE5: Burley with its clamps; Jimenez: `calculateKernel` with the fitted strength/falloff/sssWidth),",
        "compared as 1D marginals (one separable pass, or the projection of a radial kernel), bins d/4 wide to 20 d.",
        "Cells: relative L2 against Burley / against Monte Carlo / energy lost against Monte Carlo (largest channel;",
        "renormalising engines lose none; a negative value is energy gained: an artist albedo differs from its Monte",
        "Carlo reflectance within that run's error, and UE's albedo clamp at 0.009 brightens very dark channels).",
        "",
    ]
    lines += _markdown_table(engine_rows(presets))
    lines.append("")
    path = out / "README.md"
    write_bytes_atomic(path, "\n".join(lines).encode())
    return path
