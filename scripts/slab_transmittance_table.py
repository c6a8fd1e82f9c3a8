"""Generate ``sss_jax/data/slab_transmittance.json``: Monte Carlo slab transmittance T(alpha, tau) for ``model="slab"``.

    python scripts/slab_transmittance_table.py [--photons 1200000] [--nw 21] [--nv 17] [--check 40] [--nystrom]
    python scripts/slab_transmittance_table.py --recheck [--check 40] [--nystrom]   # checks of the shipped table

Each entry is one run of ``sss_jax._montecarlo.simulate``: an index-matched (eta = 1), isotropic slab of thickness
tau mean free paths, single-scattering albedo alpha, normal pencil beam; its ``total_transmittance`` (ballistic +
scattered) and standard error. Grid (``sss_jax._slab``): ``alpha = 1 - w^4`` for w uniform in [0, 1]; ``log tau``
uniform from ``log TAU_MIN`` to ``log tau_max(u)``. Entry (i, j) uses seed ``seed + i * nv + j``.

``--check K`` then runs K fresh Monte Carlo points at cell centres (the points farthest from the nodes; seeds from
``check_seed``) and stores them with the table, with the interpolation error they imply in standard errors. The
map ``A(w) = 1 - H(1) w^2`` (H at alpha = 1 - w^4, ``_fit_presets.chandrasekhar_h``) ships alongside, for the
differentiable inverse ``alpha(A)``. ``--nystrom`` compares the table, at its nodes and interpolated at every cell
centre, with a deterministic solution of the slab's transport equation (``_nystrom_transmittance``), and measures the
interpolation error alone by interpolating the deterministic node values.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import pathlib
import platform
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
MC_OPTIONS = {"eta": 1.0, "bins": 8, "r_max_mfp": 1.0}  # only the total transmittance is used: few bins are cheapest


def _albedo_map(nodes: int) -> dict:
    from sss_jax._fit_presets import chandrasekhar_h

    w = np.linspace(0.0, 1.0, nodes)
    u = w * w
    # Chandrasekhar (1960) Ch. V: the plane albedo of an index-matched isotropic half-space, A = 1 - H(1) sqrt(1-alpha)
    A = np.array([1.0 - chandrasekhar_h(1.0 - ui * ui, 1.0)[0] * ui for ui in u])
    A[0], A[-1] = 1.0, 0.0  # exact: alpha = 1 reflects everything, alpha = 0 nothing
    if not np.all(np.diff(A) < 0):
        raise RuntimeError("A(w) must decrease strictly; raise chandrasekhar_h's precision")
    return {"w": w.tolist(), "A": A.tolist(), "nodes": nodes,
            "formula": "A = 1 - H(1; alpha) u, u = w^2, alpha = 1 - w^4 (Chandrasekhar 1960 Ch. V)"}


def _run(alpha: float, tau: float, photons: int, seed: int):
    from sss_jax._montecarlo import simulate

    return simulate(float(alpha), photons=photons, slab_mfp=float(tau), seed=int(seed), **MC_OPTIONS)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--photons", type=int, default=1_200_000, help="photons per table entry")
    ap.add_argument("--nw", type=int, default=21, help="nodes in w = (1 - alpha)^(1/4)")
    ap.add_argument("--nv", type=int, default=17, help="nodes in log tau per row")
    ap.add_argument("--seed", type=int, default=1_000_000, help="seed of entry (0, 0); entry (i, j) adds i * nv + j")
    ap.add_argument("--map-nodes", type=int, default=1025, help="nodes of the A(w) map")
    ap.add_argument("--check", type=int, default=0, help="fresh Monte Carlo points at cell centres")
    ap.add_argument("--check-photons", type=int, default=None, help="photons per check point (default: --photons)")
    ap.add_argument("--check-seed", type=int, default=2_000_000)
    ap.add_argument("--nystrom", action="store_true", help="check against the deterministic transport solution")
    ap.add_argument("--recheck", action="store_true", help="run the checks on the existing --out table only")
    ap.add_argument("--out", type=pathlib.Path, default=ROOT / "sss_jax" / "data" / "slab_transmittance.json")
    args = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    if not args.recheck:
        _generate(args)
    data = json.loads(args.out.read_text())
    nw, nv = np.asarray(data["T"]).shape
    w, v = np.linspace(0.0, 1.0, nw), np.linspace(0.0, 1.0, nv)
    if args.check:
        data["interpolation_check"] = _interpolation_check(args, w, v)
        args.out.write_text(json.dumps(data, indent=1) + "\n")
        print(json.dumps({k: x for k, x in data["interpolation_check"].items() if k != "points"}, indent=1),
              file=sys.stderr)
    if args.nystrom:
        data["nystrom_check"] = _nystrom_check(args, data, w, v)
        args.out.write_text(json.dumps(data, indent=1) + "\n")
        print(json.dumps(data["nystrom_check"], indent=1), file=sys.stderr)
    return 0


def _generate(args) -> None:
    import jax

    import sss_jax
    from sss_jax import _slab

    t_start = time.perf_counter()
    w = np.linspace(0.0, 1.0, args.nw)
    v = np.linspace(0.0, 1.0, args.nv)
    alpha = 1.0 - w ** 4
    tau = np.array([[_slab.tau_of(wi * wi, vj) for vj in v] for wi in w])
    T = np.zeros_like(tau)
    se = np.zeros_like(tau)
    seconds = np.zeros_like(tau)
    for i in range(args.nw):
        for j in range(args.nv):
            r = _run(alpha[i], tau[i, j], args.photons, args.seed + i * args.nv + j)
            T[i, j], se[i, j], seconds[i, j] = r.total_transmittance, r.total_transmittance_stderr, r.seconds
        print(f"row {i + 1}/{args.nw} alpha={alpha[i]:.6f} tau {tau[i, 0]:.3g}..{tau[i, -1]:.3g} "
              f"T {T[i, 0]:.4f}..{T[i, -1]:.3g} ({seconds[i].sum():.1f} s, "
              f"total {time.perf_counter() - t_start:.0f} s)",
              file=sys.stderr, flush=True)
    if not np.all(T > 0):
        raise RuntimeError("an entry transmitted nothing: more photons or a smaller tau_max")
    mc_seconds = time.perf_counter() - t_start
    t0 = time.perf_counter()
    amap = _albedo_map(args.map_nodes)
    map_seconds = time.perf_counter() - t0
    data = {
        "description": "Total (ballistic + scattered) transmittance of an index-matched (eta = 1) isotropic slab under "
                       "a normal pencil beam, T[i][j] at single-scattering albedo alpha[i] and thickness tau[i][j] "
                       "(mean free paths), from sss_jax._montecarlo.simulate; stderr[i][j] its standard error. "
                       "Used by sss_jax.slab_transmittance (translucency model='slab').",
        "provenance": {
            "generator": "scripts/slab_transmittance_table.py",
            "sss_jax_version": sss_jax.__version__, "jax_version": jax.__version__,
            "numpy_version": np.__version__, "python": platform.python_version(),
            "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "command": "python scripts/slab_transmittance_table.py " + " ".join(sys.argv[1:]),
            "photons_per_entry": args.photons, "seed_first": args.seed, "seeds": "seed_first + i * nv + j",
            "simulate_options": {**MC_OPTIONS, "g": 0.0, "incidence": "pencil", "lanes": 4096,
                                 "batch_photons": 65536, "max_events": 100000,
                                 "unroll": "simulate's default: 4 at alpha >= 0.8, else 2"},
            "monte_carlo_seconds": round(mc_seconds, 1), "albedo_map_seconds": round(map_seconds, 1),
            "cpu_count": os.cpu_count(), "machine": platform.machine(),
        },
        "grid": {"nw": args.nw, "nv": args.nv, "tau_min": _slab.TAU_MIN, "tau_cap": _slab.TAU_CAP,
                 "k_target": _slab.K_TARGET,
                 "w": "uniform in [0, 1]; u = sqrt(1 - alpha) = w^2; alpha = 1 - w^4",
                 "v": "uniform in [0, 1]; log tau = log tau_min + v (log tau_max(u) - log tau_min)",
                 "tau_max": "1 / sqrt(tau_cap^-2 + (k(u) / k_target)^2), k(u) = sqrt(3) u / sqrt(1 + 2 u^2)"},
        "alpha": alpha.tolist(),
        "tau": tau.tolist(),
        "T": T.tolist(),
        "stderr": se.tolist(),
        "seconds": np.round(seconds, 3).tolist(),
        "albedo_map": amap,
    }
    args.out.write_text(json.dumps(data, indent=1) + "\n")
    print(f"wrote {args.out} ({args.nw} x {args.nv} entries, {args.photons} photons each, Monte Carlo "
          f"{mc_seconds:.0f} s, A(w) map {map_seconds:.0f} s)", file=sys.stderr)


def _interpolation_check(args, w: np.ndarray, v: np.ndarray) -> dict:
    """Fresh Monte Carlo at cell centres against the interpolated table: z = (T_table - T_MC) / sqrt(se_MC^2 +
    se_table^2), se_table the largest of the cell's four corners. With no interpolation error z ~ N(0, 1); the excess
    ``sqrt(max(0, mean(diff^2 - se^2)))`` estimates the interpolation error itself."""
    from sss_jax import _slab

    t0 = time.perf_counter()
    table = _slab._load(json.loads(args.out.read_text()), str(args.out))
    rng = np.random.default_rng(args.check_seed)
    cells = [(i, j) for i in range(w.size - 1) for j in range(v.size - 1)]
    pick = rng.choice(len(cells), size=min(args.check, len(cells)), replace=False)
    photons = args.check_photons or args.photons
    points = []
    for k, c in enumerate(sorted(pick)):
        i, j = cells[c]
        wc, vc = 0.5 * (w[i] + w[i + 1]), 0.5 * (v[j] + v[j + 1])
        a, t = 1.0 - wc ** 4, float(_slab.tau_of(wc * wc, vc))
        r = _run(a, t, photons, args.check_seed + k)
        model = float(_slab.slab_transmittance_mfp(a, t, _tab=table))
        s_tab = _slab.table_stderr(a, t, _tab=table)
        sigma = math.hypot(r.total_transmittance_stderr, s_tab)
        points.append({"alpha": a, "tau": t, "T_mc": r.total_transmittance, "stderr_mc": r.total_transmittance_stderr,
                       "T_table": model, "stderr_table": s_tab, "z": (model - r.total_transmittance) / sigma})
    z = np.array([p["z"] for p in points])
    diff = np.array([p["T_table"] - p["T_mc"] for p in points])
    var = np.array([p["stderr_mc"] ** 2 + p["stderr_table"] ** 2 for p in points])
    return {"points_count": len(points), "photons": photons, "seed_first": args.check_seed,
            "rms_z": float(np.sqrt(np.mean(z ** 2))), "max_abs_z": float(np.max(np.abs(z))),
            "interpolation_error_estimate": float(np.sqrt(max(0.0, float(np.mean(diff ** 2 - var))))),
            "median_stderr_table": float(np.median(table.stderr)),
            "seconds": round(time.perf_counter() - t0, 1), "points": points}


def _nystrom_transmittance(alpha: float, tau: float, panels: int) -> float:
    """Total transmittance of the index-matched isotropic slab from the integral form of its transport equation
    (Chandrasekhar 1960, Ch. XI; Case & Zweifel 1967): the scalar flux obeys
    ``phi(z) = exp(-z) + (alpha/2) int_0^tau E1(|z - z'|) phi(z') dz'`` and ``T = exp(-tau) + (alpha/2) int_0^tau
    E2(tau - z') phi(z') dz'`` (normal beam of unit flux). Nystrom with piecewise-constant phi on equal panels and
    the E1, E2 panel integrals exact (E2, E3 differences)."""
    from scipy.linalg import toeplitz
    from scipy.special import expn

    h = tau / panels
    k = np.arange(panels)
    # int over panel j of E1(|z_i - z'|) dz' at the midpoint z_i depends on |i - j| only
    first = np.where(k == 0, 2.0 - 2.0 * expn(2, 0.5 * h), np.abs(expn(2, (k - 0.5) * h) - expn(2, (k + 0.5) * h)))
    edges = np.linspace(0.0, tau, panels + 1)
    z = 0.5 * (edges[1:] + edges[:-1])
    phi = np.linalg.solve(np.eye(panels) - 0.5 * alpha * toeplitz(first), np.exp(-z))
    out = expn(3, tau - edges[1:]) - expn(3, tau - edges[:-1])
    return float(np.exp(-tau) + 0.5 * alpha * np.sum(out * phi))


def _nystrom(alpha: float, tau: float) -> float:
    """``_nystrom_transmittance`` Richardson-extrapolated from n and 2n panels (error O(h^2)): ~1e-6 here."""
    n = int(max(200, 8 * tau))
    return (4.0 * _nystrom_transmittance(alpha, tau, 2 * n) - _nystrom_transmittance(alpha, tau, n)) / 3.0


def _nystrom_check(args, data: dict, w: np.ndarray, v: np.ndarray) -> dict:
    """The table against the deterministic solution: z at the nodes (Monte Carlo noise alone), z of the interpolant at
    every cell centre (noise + interpolation), and the interpolation error alone (the interpolant of the deterministic
    node values against the deterministic centre values)."""
    from sss_jax import _slab

    t0 = time.perf_counter()
    table = _slab._load(data, str(args.out))
    T, se = np.asarray(data["T"]), np.asarray(data["stderr"])
    exact_nodes = np.array([[_nystrom(1.0 - wi ** 4, float(_slab.tau_of(wi * wi, vj))) for vj in v] for wi in w])
    z_nodes = (T - exact_nodes) / se
    wc, vc = 0.5 * (w[1:] + w[:-1]), 0.5 * (v[1:] + v[:-1])
    alpha_c = np.repeat((1.0 - wc ** 4)[:, None], vc.size, axis=1)
    tau_c = np.array([[float(_slab.tau_of(wi * wi, vj)) for vj in vc] for wi in wc])
    exact_c = np.array([[_nystrom(a, t) for a, t in zip(ra, rt)] for ra, rt in zip(alpha_c, tau_c)])
    model_c = np.asarray(_slab.slab_transmittance_mfp(alpha_c, tau_c, _tab=table))
    se_c = np.array([[_slab.table_stderr(a, t, _tab=table) for a, t in zip(ra, rt)] for ra, rt in zip(alpha_c, tau_c)])
    z_c = (model_c - exact_c) / se_c
    smooth = _slab._load({**data, "T": exact_nodes.tolist()}, "nystrom nodes")
    interp_err = np.asarray(_slab.slab_transmittance_mfp(alpha_c, tau_c, _tab=smooth)) - exact_c
    worst = np.unravel_index(np.argmax(np.abs(interp_err / se_c)), interp_err.shape)
    return {"method": "Nystrom on the scalar-flux integral equation, Richardson from n and 2n panels, "
                      "n = max(200, 8 tau)",
            "nodes": {"count": int(T.size), "rms_z": float(np.sqrt(np.mean(z_nodes ** 2))),
                      "mean_z": float(np.mean(z_nodes)), "max_abs_z": float(np.max(np.abs(z_nodes)))},
            "centres": {"count": int(z_c.size), "rms_z": float(np.sqrt(np.mean(z_c ** 2))),
                        "max_abs_z": float(np.max(np.abs(z_c))),
                        "max_abs_error": float(np.max(np.abs(model_c - exact_c))),
                        "z_uses": "stderr of the table: largest of the cell's four nodes"},
            "interpolation_only": {"max_abs_error": float(np.max(np.abs(interp_err))),
                                   "max_in_stderr": float(np.max(np.abs(interp_err / se_c))),
                                   "rms_in_stderr": float(np.sqrt(np.mean((interp_err / se_c) ** 2))),
                                   "worst_alpha": float(alpha_c[worst]), "worst_tau": float(tau_c[worst])},
            "seconds": round(time.perf_counter() - t0, 1)}


if __name__ == "__main__":
    raise SystemExit(main())
