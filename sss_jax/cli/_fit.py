"""``sss-jax fit``: presets (``fits/<material>.json``) for measured and artist materials."""

from __future__ import annotations

import argparse
import pathlib
import sys

from . import rgb_triple

EPILOG = """examples:
  sss-jax fit --all                                   # every measured and artist material into fits/
  sss-jax fit --material skin --material marble --out my_fits
  sss-jax fit --name velvet_wax --albedo 0.9,0.7,0.5 --d-mm 3,2,1.2 --out my_fits
  sss-jax fit --list

Measured materials come from Jensen et al. 2001, Table 2 (or --measured-csv with the same columns); artist materials
are surface albedo and Burley d per channel. Each preset holds Burley d, the two-Gaussian kernel (fitted as separable
renders it: the product a(x) a(y), pixel-integrated), the STA parameters, the slab transmittance of its own medium
(sss-jax transmit), their errors against Burley and Monte Carlo, the fit records, engine parameters and HLSL/GLSL
taps; see fits/README.md.
Monte Carlo runs are cached in OUT/montecarlo and reused when photons, seed and version match.
"""


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "fit",
        help="fit the two-Gaussian kernel and STA to Burley and Monte Carlo references; write presets",
        description="Fit presets for measured and artist materials and write OUT/<material>.json, OUT/schema.json, "
        "OUT/plots/<material>.png and OUT/README.md.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    which = p.add_mutually_exclusive_group()
    which.add_argument("--all", action="store_true", help="every measured and artist material (the default)")
    which.add_argument("--material", action="append", metavar="NAME", help="a material by name (repeatable)")
    which.add_argument("--list", action="store_true", help="list the known materials and exit")
    p.add_argument("--name", help="a new artist material's name (with --albedo and --d-mm)")
    p.add_argument("--albedo", type=rgb_triple, help="new artist material: surface albedo R,G,B in [0,1)")
    p.add_argument("--d-mm", type=rgb_triple, help="new artist material: Burley d R,G,B in mm")
    p.add_argument("--out", type=pathlib.Path, default=pathlib.Path("fits"), help="output directory (default fits)")
    p.add_argument("--photons", type=int, default=None, help="Monte Carlo photons per channel (default 100000)")
    p.add_argument("--seed", type=int, default=0, help="Monte Carlo seed (default 0)")
    p.add_argument("--solver", choices=("optimistix", "jaxopt"), default="optimistix", help="least-squares solver")
    p.add_argument("--taps", type=int, default=25, help="taps of the exported HLSL/GLSL kernel (default 25)")
    p.add_argument("--measured-csv", type=pathlib.Path, help="measured coefficients (default: Jensen et al. 2001)")
    p.add_argument("--no-plots", action="store_true", help="skip the per-preset plots")
    p.set_defaults(func=run)


def run(args) -> int:
    from .._fit_presets import (
        ARTIST_MATERIALS,
        DEFAULT_PHOTONS,
        fit_presets,
        measured_materials,
    )
    from .._io import SSSInputError

    try:
        measured = measured_materials(args.measured_csv)
        if args.list:
            print("measured:", ", ".join(sorted(measured)))
            print("artist:  ", ", ".join(sorted(ARTIST_MATERIALS)))
            return 0
        photons = DEFAULT_PHOTONS if args.photons is None else args.photons
        if photons < 1:
            raise ValueError(f"--photons must be a positive integer, got {photons}")
        if args.taps < 1:
            raise ValueError(f"--taps must be a positive integer, got {args.taps}")
        custom = [args.name, args.albedo, args.d_mm]
        artist = None
        if any(v is not None for v in custom):
            if any(v is None for v in custom):
                raise ValueError("a new artist material needs all of --name, --albedo R,G,B and --d-mm R,G,B")
            if args.name in measured or args.name in ARTIST_MATERIALS:
                raise ValueError(f"--name {args.name!r} is a built-in material; choose another name")
            artist = {args.name: {"albedo": list(args.albedo), "d_mm": list(args.d_mm)}}
        names = args.material if args.material else ([] if artist and not args.all else None)
        if args.out.exists() and not args.out.is_dir():
            raise ValueError(f"--out {args.out} exists and is not a directory")
        result = fit_presets(names, out_dir=args.out, photons=photons, seed=args.seed, solver=args.solver,
                             taps=args.taps, plots=not args.no_plots, measured_csv=args.measured_csv, artist=artist)
    except (ValueError, SSSInputError) as exc:
        print(f"sss-jax fit: {exc}", file=sys.stderr)
        return 2
    for name, message in result["failed"].items():
        print(f"sss-jax fit: {name} failed: {message}", file=sys.stderr)
    print(f"wrote {len(result['written'])} presets to {args.out}"
          + (f"; {len(result['failed'])} failed" if result["failed"] else ""))
    return 1 if result["failed"] else 0
