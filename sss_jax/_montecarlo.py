"""Monte Carlo reference profiles: a jitted random walk in a homogeneous medium.

Geometry: a semi-infinite half-space ``z >= 0`` or a slab ``0 <= z <= t``; light enters at the origin through the
top surface as a pencil beam at normal incidence or as diffuse (cosine-distributed) incidence. Phase function:
isotropic or Henyey–Greenstein with asymmetry ``g``. Boundaries: index-matched (``eta = 1``) or dielectric with
unpolarised Fresnel reflection on entry (the specular part is reported apart) and internal reflection, including
total internal reflection, at every exit attempt.

Lengths inside are in mean free paths (``sigma_t = 1``). Photons carry a weight: each scattering multiplies it by the
single-scattering albedo (implicit capture) and Russian roulette ends weak photons without bias. Because free paths
are memoryless, a path that reaches a boundary stops there, the boundary decides (leave or reflect), and a fresh
free path starts: no partial steps to carry.

Streaming: each jitted call runs ``lanes`` photons in parallel inside a ``lax.while_loop`` and refills a lane the
moment its photon leaves or dies, until that call's photon budget is spent, so dead photons cost nothing and memory
is ``O(lanes + bins)`` whatever the photon count. Calls repeat (with a progress bar) until all photons ran; tallies
(sums of weights and of squared weights per photon, for standard errors) accumulate on the host in float64.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["MCResult", "simulate", "simulate_material", "fresnel_unpolarised", "to_tabulated_profile",
           "albedo_from_coefficients"]

_ROULETTE_WEIGHT = 1e-3
_ROULETTE_SURVIVAL = 0.1


def fresnel_unpolarised(cos_i, n1, n2):
    """Fresnel reflectance of unpolarised light going from index n1 to n2 at incidence cosine ``cos_i`` (>= 0);
    1 beyond the critical angle (total internal reflection)."""
    cos_i = jnp.clip(cos_i, 0.0, 1.0)
    sin_t = n1 / n2 * jnp.sqrt(jnp.maximum(1 - cos_i * cos_i, 0.0))
    tir = sin_t >= 1.0
    cos_t = jnp.sqrt(jnp.maximum(1 - sin_t * sin_t, 0.0))
    rs = (n1 * cos_i - n2 * cos_t) / jnp.maximum(n1 * cos_i + n2 * cos_t, 1e-30)
    rp = (n1 * cos_t - n2 * cos_i) / jnp.maximum(n1 * cos_t + n2 * cos_i, 1e-30)
    return jnp.where(tir, 1.0, 0.5 * (rs * rs + rp * rp))


def _hg_cos(u, g):
    """Sample the Henyey–Greenstein cosine (isotropic when g = 0)."""
    safe_g = jnp.where(jnp.abs(g) < 1e-6, 1e-6, g)
    frac = (1 - safe_g * safe_g) / (1 - safe_g + 2 * safe_g * u)
    hg = (1 + safe_g * safe_g - frac * frac) / (2 * safe_g)
    return jnp.clip(jnp.where(jnp.abs(g) < 1e-6, 2 * u - 1, hg), -1.0, 1.0)


def _rotate(ux, uy, uz, cos_t, phi):
    """New direction at polar angle acos(cos_t), azimuth phi, relative to (ux, uy, uz) (MCML's formulas)."""
    sin_t = jnp.sqrt(jnp.maximum(1 - cos_t * cos_t, 0.0))
    cp, sp = jnp.cos(phi), jnp.sin(phi)
    near_pole = jnp.abs(uz) > 0.99999
    den = jnp.sqrt(jnp.maximum(1 - uz * uz, 1e-30))
    nx = sin_t * (ux * uz * cp - uy * sp) / den + ux * cos_t
    ny = sin_t * (uy * uz * cp + ux * sp) / den + uy * cos_t
    nz = -sin_t * cp * den + uz * cos_t
    px, py, pz = sin_t * cp, sin_t * sp, jnp.sign(uz) * cos_t
    return jnp.where(near_pole, px, nx), jnp.where(near_pole, py, ny), jnp.where(near_pole, pz, nz)


@dataclasses.dataclass
class MCResult:
    """Tallies of one run (lengths in mean free paths). Reflectances are fractions of the incident power."""

    albedo: float
    g: float
    eta: float
    slab_mfp: float | None
    incidence: str
    photons: int
    seed: int
    bin_edges_mfp: np.ndarray
    total_reflectance: float
    total_reflectance_stderr: float
    total_transmittance: float
    total_transmittance_stderr: float
    specular_reflectance: float
    single_scatter_reflectance: float
    single_scatter_reflectance_stderr: float
    R: np.ndarray  # reflectance per unit area (1/mfp^2) per radial bin
    R_stderr: np.ndarray
    T: np.ndarray  # transmittance per unit area through a slab
    T_stderr: np.ndarray
    capped_photons: int
    capped_weight: float
    scattering_events: int
    seconds: float

    @property
    def r_mfp(self) -> np.ndarray:
        return 0.5 * (self.bin_edges_mfp[1:] + self.bin_edges_mfp[:-1])

    def to_json(self) -> dict[str, Any]:
        from . import __version__

        r = self.r_mfp
        out = {
            "albedo": self.albedo, "g": self.g, "eta": self.eta, "slab_mfp": self.slab_mfp,
            "incidence": self.incidence, "photons": self.photons, "seed": self.seed,
            "total_reflectance": self.total_reflectance, "total_reflectance_stderr": self.total_reflectance_stderr,
            "specular_reflectance": self.specular_reflectance,
            "single_scatter_reflectance": self.single_scatter_reflectance,
            "capped_photons": self.capped_photons, "capped_weight": self.capped_weight,
            "scattering_events": self.scattering_events, "seconds": self.seconds, "version": __version__,
            "profile": {"r_mfp": r.tolist(), "rR": (r * self.R).tolist(), "rR_stderr": (r * self.R_stderr).tolist()},
        }
        if self.slab_mfp is not None:
            out["total_transmittance"] = self.total_transmittance
            out["total_transmittance_stderr"] = self.total_transmittance_stderr
            out["transmission_profile"] = {"r_mfp": r.tolist(), "rT": (r * self.T).tolist(),
                                           "rT_stderr": (r * self.T_stderr).tolist()}
        return out


def _make_kernel(lanes: int, bins: int, r_max: float, max_events: int, slab: bool, diffuse: bool):
    """The jitted batch runner for one static configuration."""

    @jax.jit
    def run(key, budget, albedo, g, eta, thickness):
        f32 = jnp.float32
        n_bins = bins
        inv_dr = n_bins / r_max
        r_sp = ((eta - 1) / (eta + 1)) ** 2

        def launch(key, count):
            """``count``-shaped fresh photon states."""
            k1, k2 = jax.random.split(key)
            if diffuse:
                u = jax.random.uniform(k1, count, f32)
                cos_out = jnp.sqrt(u)  # cosine-weighted directions outside
                weight = 1 - fresnel_unpolarised(cos_out, 1.0, eta)
                sin_in = jnp.sqrt(jnp.maximum(1 - cos_out**2, 0.0)) / eta
                phi = 2 * math.pi * jax.random.uniform(k2, count, f32)
                uz = jnp.sqrt(jnp.maximum(1 - sin_in**2, 0.0))
                ux, uy = sin_in * jnp.cos(phi), sin_in * jnp.sin(phi)
            else:
                weight = jnp.full(count, 1 - r_sp, f32)
                ux = jnp.zeros(count, f32)
                uy = jnp.zeros(count, f32)
                uz = jnp.ones(count, f32)
            zeros = jnp.zeros(count, f32)
            return dict(x=zeros, y=zeros, z=zeros, ux=ux, uy=uy, uz=uz, w=weight.astype(f32),
                        n=jnp.zeros(count, jnp.int32))

        state = launch(jax.random.fold_in(key, 0), (lanes,))
        alive = jnp.arange(lanes) < budget
        tallies = dict(
            hist=jnp.zeros((4, n_bins + 1), f32),
            R1=jnp.zeros((), f32), R1sq=jnp.zeros((), f32),
            capped=jnp.zeros((), jnp.int32), capped_w=jnp.zeros((), f32), events=jnp.zeros((), jnp.int32),
        )
        launched = jnp.minimum(budget, lanes)

        def cond(carry):
            _, alive, _, _, _ = carry
            return jnp.any(alive)

        def body(carry):
            state, alive, launched, tallies, it = carry
            k = jax.random.fold_in(key, it + 1)
            u_step, u_fres, u_cos, u_phi, u_rr = jax.random.uniform(k, (5, lanes), f32)
            x, y, z, ux, uy, uz, w, n = (state[s] for s in ("x", "y", "z", "ux", "uy", "uz", "w", "n"))
            step = -jnp.log(jnp.maximum(u_step, 1e-30))
            z_new = z + uz * step
            hits_top = z_new < 0
            hits_bottom = (z_new > thickness) if slab else jnp.zeros_like(hits_top)
            boundary = hits_top | hits_bottom
            # distance to the boundary crossed (memoryless free paths: stop there, decide, restart)
            t_b = jnp.where(hits_top, -z / jnp.where(uz < 0, uz, -1.0),
                            (thickness - z) / jnp.where(uz > 0, uz, 1.0))
            t = jnp.where(boundary, t_b, step)
            x, y = x + ux * t, y + uy * t
            z = jnp.where(hits_top, 0.0, jnp.where(hits_bottom, thickness, z_new))
            reflect = u_fres < fresnel_unpolarised(jnp.abs(uz), eta, 1.0)
            leaves = boundary & ~reflect & alive
            uz = jnp.where(boundary & reflect, -uz, uz)
            # scattering where no boundary was met
            scatter = ~boundary & alive
            cos_t = _hg_cos(u_cos, g)
            nx, ny, nz = _rotate(ux, uy, uz, cos_t, 2 * math.pi * u_phi)
            ux, uy, uz = (jnp.where(scatter, a, b) for a, b in ((nx, ux), (ny, uy), (nz, uz)))
            w = jnp.where(scatter, w * albedo, w)
            n = n + scatter.astype(jnp.int32)
            # tallies of the photons leaving now
            r = jnp.sqrt(x * x + y * y)
            bin_idx = jnp.minimum((r * inv_dr).astype(jnp.int32), n_bins)  # the last bin collects r >= r_max
            top_w = jnp.where(leaves & hits_top, w, 0.0)
            bot_w = jnp.where(leaves & hits_bottom, w, 0.0)
            tallies = dict(tallies)
            # one scatter-add for all four histograms: rows R, R^2, T, T^2
            exit_w = top_w + bot_w
            row = jnp.where(hits_bottom, 2, 0)
            hist = tallies["hist"].at[row, bin_idx].add(exit_w).at[row + 1, bin_idx].add(exit_w * exit_w)
            tallies["hist"] = hist
            single = jnp.where(n == 1, top_w, 0.0)
            tallies["R1"] = tallies["R1"] + jnp.sum(single)
            tallies["R1sq"] = tallies["R1sq"] + jnp.sum(single * single)
            tallies["events"] = tallies["events"] + jnp.sum(scatter, dtype=jnp.int32)
            # Russian roulette on weak photons, and the event cap
            weak = alive & ~leaves & (w < _ROULETTE_WEIGHT)
            survive = u_rr < _ROULETTE_SURVIVAL
            w = jnp.where(weak, jnp.where(survive, w / _ROULETTE_SURVIVAL, 0.0), w)
            died = weak & ~survive
            capped = alive & ~leaves & ~died & (n >= max_events)
            tallies["capped"] = tallies["capped"] + jnp.sum(capped, dtype=jnp.int32)
            tallies["capped_w"] = tallies["capped_w"] + jnp.sum(jnp.where(capped, w, 0.0))
            alive = alive & ~leaves & ~died & ~capped
            # refill finished lanes with new photons while the budget lasts
            free = ~alive
            rank = jnp.cumsum(free, dtype=jnp.int32) - 1
            refill = free & (launched + rank < budget)
            fresh = launch(jax.random.fold_in(k, 7), (lanes,))
            state = dict(x=x, y=y, z=z, ux=ux, uy=uy, uz=uz, w=w, n=n)
            state = {s: jnp.where(refill, fresh[s], v) for s, v in state.items()}
            launched = launched + jnp.sum(refill, dtype=jnp.int32)
            alive = alive | refill
            return state, alive, launched, tallies, it + 1

        _, _, _, tallies, _ = jax.lax.while_loop(cond, body, (state, alive, launched, tallies, jnp.int32(0)))
        hist = tallies.pop("hist")
        return dict(tallies, R=hist[0], R2=hist[1], T=hist[2], T2=hist[3])

    return run


_KERNELS: dict[tuple, Any] = {}


def simulate(
    albedo: float,
    *,
    photons: int = 100_000,
    g: float = 0.0,
    eta: float = 1.0,
    slab_mfp: float | None = None,
    incidence: str = "pencil",
    seed: int = 0,
    bins: int = 200,
    r_max_mfp: float = 20.0,
    lanes: int = 1 << 15,
    batch_photons: int = 1 << 20,
    max_events: int = 100_000,
    progress: bool = False,
) -> MCResult:
    """Random-walk reflectance (and slab transmittance) of a homogeneous medium, in mean free paths.

    ``albedo``: single-scattering albedo ``sigma_s / sigma_t`` in [0, 1]; ``g``: HG asymmetry in (-1, 1); ``eta``:
    relative index of refraction (>= 1); ``slab_mfp``: slab thickness (None: semi-infinite); ``incidence``:
    ``"pencil"`` (normal) or ``"diffuse"``. Returns tallies with standard errors (per photon, so bins and totals
    carry their own statistical error).
    """
    if not (0.0 <= albedo <= 1.0):
        raise ValueError(f"albedo must lie in [0, 1], got {albedo}")
    if not (-1.0 < g < 1.0):
        raise ValueError(f"g must lie in (-1, 1), got {g}")
    if not (eta >= 1.0 and math.isfinite(eta)):
        raise ValueError(f"eta must be a finite number >= 1, got {eta}")
    if not isinstance(photons, (int, np.integer)) or photons < 1:
        raise ValueError(f"photons must be a positive integer, got {photons!r}")
    if slab_mfp is not None and not (slab_mfp > 0 and math.isfinite(slab_mfp)):
        raise ValueError(f"slab thickness must be a finite positive length, got {slab_mfp}")
    if incidence not in ("pencil", "diffuse"):
        raise ValueError(f"incidence must be 'pencil' or 'diffuse', got {incidence!r}")
    lanes = int(min(lanes, photons))
    key_cfg = (lanes, bins, float(r_max_mfp), int(max_events), slab_mfp is not None, incidence == "diffuse")
    if key_cfg not in _KERNELS:
        _KERNELS[key_cfg] = _make_kernel(*key_cfg)
    run = _KERNELS[key_cfg]
    totals = {k: 0.0 for k in ("R1", "R1sq", "capped", "capped_w", "events")}
    hist = {k: np.zeros(bins + 1) for k in ("R", "R2", "T", "T2")}
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=photons, unit="photon", unit_scale=True, desc="montecarlo")
    t0 = time.perf_counter()
    done, call = 0, 0
    thickness = np.float32(slab_mfp if slab_mfp is not None else np.inf)
    while done < photons:
        n = min(batch_photons, photons - done)
        key = jax.random.fold_in(jax.random.PRNGKey(seed), call)
        t = run(key, jnp.int32(n), jnp.float32(albedo), jnp.float32(g), jnp.float32(eta), thickness)
        t = jax.tree.map(np.asarray, t)
        for k in hist:
            hist[k] += t[k].astype(np.float64)
        for k in totals:
            totals[k] += float(t[k])
        done += n
        call += 1
        if bar is not None:
            bar.update(n)
    if bar is not None:
        bar.close()
    seconds = time.perf_counter() - t0
    N = float(photons)

    def mean_err(s, s2):
        mean = s / N
        var = np.maximum(s2 / N - mean * mean, 0.0)
        return mean, np.sqrt(var / N)

    edges = np.linspace(0.0, r_max_mfp, bins + 1)
    area = math.pi * (edges[1:] ** 2 - edges[:-1] ** 2)
    R_bin, R_bin_err = mean_err(hist["R"], hist["R2"])
    T_bin, T_bin_err = mean_err(hist["T"], hist["T2"])
    # a photon leaves once, so its total contribution is its weight in one bin: the per-photon variance of the total
    # is the sum of the per-bin second moments
    R_tot, R_tot_err = mean_err(hist["R"].sum(), hist["R2"].sum())
    T_tot, T_tot_err = mean_err(hist["T"].sum(), hist["T2"].sum())
    R1, R1_err = mean_err(totals["R1"], totals["R1sq"])
    r_sp = ((eta - 1) / (eta + 1)) ** 2 if incidence == "pencil" else float("nan")
    return MCResult(
        albedo=float(albedo), g=float(g), eta=float(eta), slab_mfp=slab_mfp, incidence=incidence,
        photons=int(photons), seed=int(seed), bin_edges_mfp=edges,
        total_reflectance=float(R_tot), total_reflectance_stderr=float(R_tot_err),
        total_transmittance=float(T_tot), total_transmittance_stderr=float(T_tot_err),
        specular_reflectance=r_sp, single_scatter_reflectance=float(R1), single_scatter_reflectance_stderr=float(R1_err),
        R=R_bin[:bins] / area, R_stderr=R_bin_err[:bins] / area, T=T_bin[:bins] / area, T_stderr=T_bin_err[:bins] / area,
        capped_photons=int(totals["capped"]), capped_weight=float(totals["capped_w"]) / N,
        scattering_events=int(totals["events"]), seconds=seconds,
    )


def albedo_from_coefficients(sigma_s: float, sigma_a: float) -> tuple[float, float]:
    """(single-scattering albedo, mean free path in mm) from scattering and absorption coefficients in 1/mm."""
    if not (sigma_s >= 0 and sigma_a >= 0 and sigma_s + sigma_a > 0):
        raise ValueError(f"coefficients must be >= 0 with a positive sum, got sigma_s={sigma_s}, sigma_a={sigma_a}")
    sigma_t = sigma_s + sigma_a
    return sigma_s / sigma_t, 1.0 / sigma_t


def simulate_material(sigma_s_prime, sigma_a, *, eta: float = 1.0, **kwargs) -> list[MCResult]:
    """One run per channel from reduced scattering and absorption coefficients (1/mm, shape (3,)), with an
    isotropic phase function (similarity theory: ``sigma_s' = sigma_s (1 - g)``)."""
    results = []
    for s, a in zip(np.atleast_1d(sigma_s_prime), np.atleast_1d(sigma_a)):
        alb, _ = albedo_from_coefficients(float(s), float(a))
        results.append(simulate(alb, eta=eta, **kwargs))
    return results


def to_tabulated_profile(results: MCResult | list[MCResult], mfp_mm: float | list[float]):
    """The reflectance profile(s) as a ``TabulatedProfile`` in millimetres (one channel per result)."""
    from ._profiles import TabulatedProfile

    results = [results] if isinstance(results, MCResult) else list(results)
    mfps = np.broadcast_to(np.asarray(mfp_mm, np.float64), (len(results),))
    # one radius grid: the first channel's, every channel's R resampled onto it (in 1/mm^2)
    r0 = results[0].r_mfp * mfps[0]
    cols = [np.interp(r0, res.r_mfp * m, res.R / (m * m), right=0.0) for res, m in zip(results, mfps)]
    return TabulatedProfile(r0, np.stack(cols, axis=-1))
