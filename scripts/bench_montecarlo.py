"""Monte Carlo throughput: sss_jax's jitted random walk against a straightforward vectorised NumPy random walk of
the same physics (semi-infinite, pencil beam, isotropic, eta = 1, implicit capture, Russian roulette), side by side.

    python scripts/bench_montecarlo.py [--albedo 0.9] [--photons 200000]

Prints photons/s and scattering events/s of both and their ratio (goal: sss_jax >= 5x NumPy events/s).
"""

import argparse
import math
import time

import numpy as np


def numpy_walk(albedo: float, photons: int, seed: int = 0, bins: int = 200, r_max: float = 20.0):
    """Every live photon advances one event per iteration; finished photons are compacted away."""
    rng = np.random.default_rng(seed)
    x = np.zeros(photons); y = np.zeros(photons); z = np.zeros(photons)
    ux = np.zeros(photons); uy = np.zeros(photons); uz = np.ones(photons); w = np.ones(photons)
    hist = np.zeros(bins + 1)
    events = 0
    while x.size:
        step = -np.log(np.maximum(rng.random(x.size), 1e-300))
        z_new = z + uz * step
        top = z_new < 0
        t = np.where(top, -z / np.where(uz < 0, uz, -1.0), step)
        x += ux * t; y += uy * t; z = np.where(top, 0.0, z_new)
        r = np.sqrt(x[top] ** 2 + y[top] ** 2)
        np.add.at(hist, np.minimum((r * bins / r_max).astype(int), bins), w[top])
        keep = ~top
        x, y, z, ux, uy, uz, w = (a[keep] for a in (x, y, z, ux, uy, uz, w))
        events += x.size
        # isotropic scattering and implicit capture
        cos_t = 2 * rng.random(x.size) - 1
        phi = 2 * math.pi * rng.random(x.size)
        sin_t = np.sqrt(1 - cos_t ** 2)
        ux, uy, uz = sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t
        w = w * albedo
        weak = w < 1e-3
        survive = rng.random(x.size) < 0.1
        w = np.where(weak, np.where(survive, w / 0.1, 0.0), w)
        keep = ~(weak & ~survive)
        x, y, z, ux, uy, uz, w = (a[keep] for a in (x, y, z, ux, uy, uz, w))
    return hist.sum() / photons, events


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--albedo", type=float, default=0.9)
    ap.add_argument("--photons", type=int, default=200_000)
    args = ap.parse_args()
    from sss_jax._montecarlo import simulate

    simulate(args.albedo, photons=min(args.photons, 50_000), seed=99)  # compile outside the timing
    t0 = time.perf_counter()
    res = simulate(args.albedo, photons=args.photons, seed=1)
    t_jax = time.perf_counter() - t0
    t0 = time.perf_counter()
    r_np, ev_np = numpy_walk(args.albedo, args.photons, seed=1)
    t_np = time.perf_counter() - t0
    ev_jax = res.scattering_events
    print(f"albedo {args.albedo}, {args.photons} photons, semi-infinite, isotropic, eta 1")
    print(f"{'':10s} {'R_total':>9s} {'photons/s':>12s} {'events/s':>12s}")
    print(f"{'sss_jax':10s} {res.total_reflectance:9.5f} {args.photons / t_jax:12.4g} {ev_jax / t_jax:12.4g}")
    print(f"{'numpy':10s} {r_np:9.5f} {args.photons / t_np:12.4g} {ev_np / t_np:12.4g}")
    ratio = (ev_jax / t_jax) / (ev_np / t_np)
    print(f"events/s ratio sss_jax / numpy: {ratio:.2f}x (goal >= 5x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
