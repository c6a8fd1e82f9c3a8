"""``sss-jax transmit``: the fraction of a back light that a slab of a preset's medium lets through."""

from __future__ import annotations

import argparse
import math
import pathlib
import sys

EPILOG = """examples:
  sss-jax transmit --preset skin1 --thickness-mm 1,2,4
  sss-jax transmit --preset marble --thickness-mm 0.5,1,2,5,10 --json marble_T.json

T is the total (unscattered and scattered) fraction of a normally incident back light that leaves the front face of
a slab of the preset's medium (its transmittance table: Monte Carlo through slabs of its reduced coefficients with
its eta on both faces, interpolated), per channel R, G, B. All of the medium's absorption is in T, and no albedo
multiplies it. translucency(model="slab") adds only T's scattered part: light x T_diffuse x cos x P(N.V), the
unscattered beam reaching the camera only where it looks into the light (not drawn by a screen-space pass); P spreads
the diffuse light over view directions as the slab lets it out.
JSON: {"preset": NAME, "transmittance": [{"thickness_mm": t, "rgb": [R, G, B]}, ...]}.
"""


def _thicknesses(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]  # an empty item ("1,,2") is a typo, refused
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated thicknesses in mm, got {text!r}") from None
    if not values or not all(math.isfinite(v) and v >= 0 for v in values):
        raise argparse.ArgumentTypeError(f"thicknesses must be finite numbers >= 0 (mm), got {text!r}")
    return values


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "transmit",
        help="back light through slabs of a preset's medium, per channel",
        description="Print (and optionally write as JSON) the fraction of a normally incident back light that leaves "
        "the front face of slabs of the given thicknesses of a preset's medium, per channel.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--preset", required=True, help="preset name (fits/) or path to a preset JSON")
    p.add_argument("--thickness-mm", type=_thicknesses, required=True, metavar="T1,T2,...",
                   help="slab thicknesses in mm, comma-separated")
    p.add_argument("--json", type=pathlib.Path, help="write the result as JSON here")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from .._io import SSSInputError, check_writable, write_json_atomic
    from .._presets import load_preset

    try:
        preset = load_preset(args.preset)
        if preset.medium is None:
            raise SSSInputError(f"{preset.path}: preset carries no medium transmittance (a 'transmittance' block); "
                                "fit it again with sss-jax fit")
        if args.json is not None:
            check_writable(args.json, create_dirs=False)
    except SSSInputError as exc:
        print(f"sss-jax transmit: {exc}", file=sys.stderr)
        return 2
    T = np.asarray(preset.medium.transmittance(np.asarray(args.thickness_mm, np.float64)), np.float64)
    rows = [{"thickness_mm": float(t), "rgb": [float(v) for v in T[i]]} for i, t in enumerate(args.thickness_mm)]
    print(f"{preset.name}: transmittance of a normal back light through a slab of its medium")
    print("thickness_mm        R        G        B")
    for r in rows:
        print(f"{r['thickness_mm']:12.4g} " + " ".join(f"{v:8.4f}" for v in r["rgb"]))
    if args.json is not None:
        write_json_atomic(args.json, {"preset": preset.name, "transmittance": rows})
    return 0
