"""``sss-jax montecarlo``: a random-walk reference profile."""

from __future__ import annotations

import argparse
import math
import pathlib
import sys

EPILOG = """examples:
  sss-jax montecarlo --albedo 0.9 --photons 1000000 --json mc.json
  sss-jax montecarlo --albedo 0.99 --photons 200000 --eta 1.3 --g 0.8 --slab-mm 2 --mfp-mm 0.5 --json slab.json

Lengths in the JSON profile are in mean free paths (profile.r_mfp); --slab-mm is turned into mean free paths with
--mfp-mm (default 1 mm, so by default a slab thickness is given in mean free paths).
"""


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "montecarlo",
        help="random-walk reflectance profile of a homogeneous medium",
        description="Simulate light in a homogeneous medium (semi-infinite or a slab) with a jitted random walk and "
        "write the radial reflectance profile, totals and their standard errors as JSON.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--albedo", type=float, required=True, help="single-scattering albedo sigma_s / sigma_t in [0, 1]")
    p.add_argument("--photons", type=int, required=True, help="number of photons (streamed in batches)")
    p.add_argument("--eta", type=float, default=1.0, help="relative index of refraction (default 1: index-matched)")
    p.add_argument("--g", type=float, default=0.0, help="Henyey-Greenstein asymmetry (default 0: isotropic)")
    p.add_argument("--slab-mm", type=float, help="slab thickness in mm (default: semi-infinite)")
    p.add_argument("--mfp-mm", type=float, default=1.0, help="mean free path in mm (default 1)")
    p.add_argument("--incidence", choices=("pencil", "diffuse"), default="pencil")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-events", type=int, default=100_000, help="scattering events after which absorption turns "
                   "analog (unbiased: no photon is dropped there; only after 1000 times as many, counted in "
                   "capped_photons)")
    p.add_argument("--json", type=pathlib.Path, required=True, help="output JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from .._io import SSSInputError, check_writable, write_json_atomic
    from .._montecarlo import simulate

    try:
        if not (args.mfp_mm > 0 and math.isfinite(args.mfp_mm)):
            raise ValueError(f"--mfp-mm must be a finite positive length, got {args.mfp_mm}")
        if args.slab_mm is not None and not (args.slab_mm > 0 and math.isfinite(args.slab_mm)):
            raise ValueError(f"--slab-mm must be a finite positive thickness, got {args.slab_mm}")
        if args.max_events < 1:
            raise ValueError(f"--max-events must be >= 1, got {args.max_events}")
        if not args.json.parent.is_dir():
            raise ValueError(f"--json: directory {args.json.parent} does not exist")
        try:  # before the simulation: a folder that takes no file fails now, not after minutes of work
            check_writable(args.json, create_dirs=False)
        except SSSInputError as exc:
            raise ValueError(f"--json: {exc}") from None
        slab = None if args.slab_mm is None else args.slab_mm / args.mfp_mm
        result = simulate(args.albedo, photons=args.photons, g=args.g, eta=args.eta, slab_mfp=slab,
                          incidence=args.incidence, seed=args.seed, max_events=args.max_events,
                          progress=sys.stderr.isatty() or args.photons >= 1_000_000)
    except ValueError as exc:
        print(f"sss-jax montecarlo: {exc}", file=sys.stderr)
        return 2
    data = result.to_json()
    data["mfp_mm"] = args.mfp_mm
    try:
        write_json_atomic(args.json, data)
    except (OSError, ValueError) as exc:  # the folder changed during the run
        print(f"sss-jax montecarlo: --json {args.json}: cannot write ({exc})", file=sys.stderr)
        return 1
    print(f"total reflectance {result.total_reflectance:.5f} +- {result.total_reflectance_stderr:.5f}"
          + (f", transmittance {result.total_transmittance:.5f} +- {result.total_transmittance_stderr:.5f}"
             if slab is not None else "")
          + f" ({result.photons} photons, {result.scattering_events / max(result.seconds, 1e-9):.3g} events/s)")
    return 0
