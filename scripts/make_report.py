"""The error report from Python: measure with ``sj.evaluate_frames``, lay out with ``sj.report``.

Default: the Blender 3.4 / Cycles scene of ../shared/reference/blender (white-Lambertian passes as input, Cycles'
own Burley render as the truth, the material of its README), every technique, the full sample and tap grid.

    python scripts/make_report.py --out report_blender
    python scripts/make_report.py IN.exr --truth TRUTH.exr --albedo 0.8,0.6,0.5 --d-mm 3,1.4,0.8 --out rep

``--section TITLE=FILE.html`` adds a section of your own (e.g. a fit's before/after) after the trade. Like the other
scripts it imports the installed ``sss_jax`` (``pip install -e .``; or run with ``PYTHONPATH=.`` from the checkout).
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys

import sss_jax as sj

BLENDER = pathlib.Path(__file__).resolve().parents[2] / "shared" / "reference" / "blender"


def _triple(text: str) -> tuple[float, float, float]:
    values = tuple(float(v) for v in text.split(","))
    return values * 3 if len(values) == 1 else values


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inputs", nargs="*", default=[str(BLENDER / "irradiance_backlit.exr")])
    p.add_argument("--truth", nargs="*", default=None)
    p.add_argument("--out", type=pathlib.Path, required=True)
    # Cycles 3.x: d = radius / (4 pi), radius (0.4, 0.25, 0.15) m (reference/blender/README.md)
    p.add_argument("--albedo", type=_triple, default=(0.85, 0.75, 0.55))
    p.add_argument("--d-mm", type=_triple, default=tuple(r / (4 * math.pi) for r in (400.0, 250.0, 150.0)))
    p.add_argument("--techniques", default="separable,burley")
    p.add_argument("--taps", default="9,17,25")
    p.add_argument("--samples", default="8,16,32,64")
    p.add_argument("--radius-px", type=int)
    p.add_argument("--section", action="append", default=[], help="TITLE=FILE.html: an extra section")
    args = p.parse_args(argv)
    truth = args.truth if args.truth is not None else (
        [str(BLENDER / "burley_backlit.exr")] if args.inputs == [str(BLENDER / "irradiance_backlit.exr")] else None)
    extra = []
    for item in args.section:
        title, _, path = item.partition("=")
        extra.append((title, pathlib.Path(path).read_text()))
    try:
        data = sj.evaluate_frames(
            args.inputs, sj.BurleyMaterial(args.albedo, args.d_mm), truth=truth,
            techniques=args.techniques.split(","), taps=[int(v) for v in args.taps.split(",")],
            samples=[int(v) for v in args.samples.split(",")], use_albedo_pass=False, radius_px=args.radius_px,
            cache_dir=args.out / "cache", progress=True)
    except (ValueError, OSError) as exc:
        print(f"make_report: {exc}", file=sys.stderr)
        return 2
    print(sj.report(data, args.out, extra_sections=extra, images=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
