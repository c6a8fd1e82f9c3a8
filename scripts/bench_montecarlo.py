"""Monte Carlo throughput: sss_jax's jitted random walk against a straightforward vectorised NumPy random walk of
the same physics (semi-infinite, pencil beam, isotropic, eta = 1, implicit capture, Russian roulette), side by side.

    python scripts/bench_montecarlo.py [--albedo 0.9] [--photons 200000] [--rounds 3] [--json OUT]

Prints photons/s and scattering events/s of both and their ratio (goal: sss_jax >= 5x NumPy events/s). sss_jax runs
its batches on all cores by default (one jitted walk per core); the one-thread figure is printed beside it, since the
NumPy walk uses one core.
"""

import argparse
import json
import math
import pathlib
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
    ap.add_argument("--rounds", type=int, default=3, help="alternating timed rounds of each walk; the best counts")
    ap.add_argument("--json", type=pathlib.Path, help="also write the figures here")
    args = ap.parse_args()
    from sss_jax._machine import usable_cores
    from sss_jax._montecarlo import simulate

    threads = usable_cores()
    walks = {
        # the default: batches on every core, each batch a jitted walk on one core
        "sss_jax": lambda seed: simulate(args.albedo, photons=args.photons, seed=seed),
        "sss_jax_1thread": lambda seed: simulate(args.albedo, photons=args.photons, seed=seed, workers=1),
        "numpy": lambda seed: numpy_walk(args.albedo, args.photons, seed=seed),
    }
    simulate(args.albedo, photons=args.photons, seed=99)  # compile outside the timing
    best: dict[str, tuple[float, float, int]] = {}
    # rounds alternate the walks so that a slow spell of a shared machine hits both sides alike
    for rnd in range(args.rounds):
        for name, walk in walks.items():
            t0 = time.perf_counter()
            res = walk(rnd + 1)
            seconds = time.perf_counter() - t0
            r_total, events = (res.total_reflectance, res.scattering_events) if name != "numpy" else res
            if name not in best or seconds < best[name][0]:
                best[name] = (seconds, r_total, events)
    print(f"albedo {args.albedo}, {args.photons} photons, semi-infinite, isotropic, eta 1; best of {args.rounds} rounds, "
          f"{threads} CPU cores")
    print(f"{'':16s} {'R_total':>9s} {'photons/s':>12s} {'events/s':>12s}")
    figures = {}
    for name, (seconds, r_total, events) in best.items():
        figures[name] = dict(seconds=seconds, total_reflectance=r_total, scattering_events=int(events),
                             photons_per_s=args.photons / seconds, events_per_s=events / seconds)
        print(f"{name:16s} {r_total:9.5f} {args.photons / seconds:12.4g} {events / seconds:12.4g}")
    ratio = figures["sss_jax"]["events_per_s"] / figures["numpy"]["events_per_s"]
    ratio_1 = figures["sss_jax_1thread"]["events_per_s"] / figures["numpy"]["events_per_s"]
    print(f"events/s ratio sss_jax / numpy: {ratio:.2f}x (goal >= 5x); one thread: {ratio_1:.2f}x")
    if args.json is not None:
        data = dict(albedo=args.albedo, photons=args.photons, rounds=args.rounds, cpu_cores=threads, walks=figures,
                    ratios={"events_per_s_vs_numpy": ratio, "events_per_s_vs_numpy_one_thread": ratio_1},
                    goal={"events_per_s_vs_numpy": 5.0})
        args.json.write_text(json.dumps(data, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
