"""``sss-jax advise``: the cheapest technique and sample count within a ΔE budget, from the measured trade."""

from __future__ import annotations

import argparse
import pathlib
import sys

from ._options import add_technique_flags, option_arguments, technique_options

# the techniques whose counts the advisor weighs (beside local shading)
ADVISED = ("separable", "burley")

EPILOG = """examples:
  sss-jax advise --material skin --max-delta-e 1.0
  sss-jax advise --material marble --scene demo --scene-scale 4 --size 128x96 --max-delta-e 0.5 --json advice.json
  sss-jax advise --material demo_skin --max-delta-e 1.0        # the demo scene's own skin (not the preset skin)
"""


def _size(text: str) -> tuple[int, int]:
    """WIDTHxHEIGHT, as ``sss-jax demo`` takes it; returns (height, width)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--size must be WIDTHxHEIGHT (e.g. 96x72), got {text!r}") from None
    if h < 8 or w < 8:
        raise argparse.ArgumentTypeError(f"--size must be at least 8x8, got {text!r}")
    return h, w


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "advise",
        help="pick the cheapest technique and sample count whose error stays within a dE2000 budget",
        description="Run local shading, separable (5..25 taps) and Burley (4..64 samples) on the scene made of the "
        "material, time each on this machine (repeated: median and interquartile range), measure the mean CIEDE2000 "
        "against the reference, and pick the fastest within --max-delta-e; where the fastest one's timings overlap "
        "another's within the budget (within the noise), say so and pick the more accurate. Prints the table and the "
        "reason.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--material", required=True, help="a demo material (skin, marble, wax) or a preset name or file")
    p.add_argument("--scene", default="demo", choices=["demo"], help="the scene measured on (default: demo)")
    p.add_argument("--scene-scale", type=float, default=1.0,
                   help="size of the scene's objects relative to the demo's (scales mm per scene unit; default 1)")
    p.add_argument("--size", type=_size, default=(72, 96), help="scene size WIDTHxHEIGHT in pixels, as `sss-jax demo` takes it (default 96x72, cheap)")
    p.add_argument("--max-delta-e", type=float, required=True, help="budget: mean CIEDE2000 against the reference")
    p.add_argument("--repeats", type=int, default=5,
                   help="timed runs per candidate: median and interquartile range; candidates whose ranges overlap "
                   "are within the noise and the more accurate one is preferred (default 5)")
    p.add_argument("--json", type=pathlib.Path, help="write the table and the choice as JSON")
    # the candidates' own options (their counts are the advisor's candidates)
    add_technique_flags(p, techniques=ADVISED, exclude=("samples", "taps", "radius_px", "albedo", "thickness"))
    p.set_defaults(func=run)


def run(args) -> int:
    from .._advise import advise, resolve_material

    try:
        if not (args.max_delta_e >= 0):
            raise ValueError(f"--max-delta-e must be >= 0, got {args.max_delta_e}")
        if not (args.scene_scale > 0 and args.scene_scale < float("inf")):
            raise ValueError(f"--scene-scale must be a finite positive number, got {args.scene_scale}")
        if args.repeats < 1:
            raise ValueError(f"--repeats must be >= 1, got {args.repeats}")
        if args.json is not None and not args.json.parent.exists():
            raise ValueError(f"directory {args.json.parent} does not exist")
        resolve_material(args.material)
        options = {t: technique_options(args, t, others=ADVISED) for t in ADVISED}
        extra = option_arguments(advise, options, "advise")
    except ValueError as exc:
        print(f"sss-jax advise: {exc}", file=sys.stderr)
        return 2
    advice = advise(args.material, max_delta_e=args.max_delta_e, size=args.size, scene_scale=args.scene_scale,
                    repeats=args.repeats, progress=lambda m: print(m, file=sys.stderr, flush=True), **extra)
    h, w = args.size
    print(f"material {advice.material}, scene {args.scene} {w}x{h} x{args.scene_scale:g}, "
          f"budget mean dE2000 <= {args.max_delta_e:g}")
    print(advice.table())
    if args.json:
        from .._io import write_json_atomic

        write_json_atomic(args.json, advice.to_json())
    return 0 if advice.choice is not None else 1
