"""The Monte Carlo references of a preset, cached in ``fits/montecarlo/`` with their provenance and reused only when
all of it matches; Burley's d fitted to the Monte Carlo profile."""

from __future__ import annotations

import json
import math
import pathlib
import time
from collections.abc import Callable
from typing import Any

import jax.numpy as jnp
import numpy as np

from .._version import __version__
from .._io import write_bytes_atomic
from .._montecarlo import MCResult, simulate
from .._profiles import burley_R, scaling_searchlight
from ._sources import MC_TERMINATION, MEDIUM_SLAB_PHOTONS_FRACTION, SLAB_PHOTONS_FRACTION, SLAB_T_OVER_D, chandrasekhar_h

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
    from .._slab import MEDIUM_TAU_NODES, medium_slab_table

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
    from .._fitting import _solve

    r = result.r_mfp * mfp_mm
    R_mc = result.R / (mfp_mm**2) / max(result.total_reflectance, 1e-300)
    data = (jnp.asarray(r), jnp.asarray(R_mc), jnp.asarray(float(np.linalg.norm(r * R_mc))))
    t0 = time.perf_counter()
    x, outcome, it = _solve(_burley_residual, np.array([d0_mm]), np.array([d0_mm / 20]), np.array([d0_mm * 20]),
                            solver, args=data)
    err = float(jnp.linalg.norm(_burley_residual(jnp.asarray(x), data)))
    return {"d_mm": float(x[0]), "outcome": outcome, "iterations": it, "seconds": time.perf_counter() - t0,
            "error_relative_l2": err}
