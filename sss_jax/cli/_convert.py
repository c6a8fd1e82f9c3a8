"""``sss-jax convert``: one material in another engine's units."""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

from . import rgb_triple

EPILOG = """examples:
  sss-jax convert --from sss_jax --to blender --albedo 0.8,0.6,0.5 --d-mm 3,1.4,0.8
  sss-jax convert --from blender --to unreal --albedo 0.8,0.6,0.5 --radius 1,0.2,0.1 --scale 0.05 --json ue.json
  sss-jax convert --from hdrp --to eevee --albedo 0.8,0.6,0.5 --scattering-color 0.7,0.3,0.2 --multiplier 4
  sss-jax convert --from sss_jax --to jimenez --albedo 0.8,0.6,0.5 --mfp-mm 8,4,2 --json jimenez.json

Parameters per engine (all lengths per channel as R,G,B; one number means all three):
  sss_jax   --albedo, --d-mm (Burley d, mm) or --mfp-mm (d = mfp / s(A), diffuse-transmission fit)
  blender   --albedo (Subsurface Color), --radius (scene units), --scale (1), --mm-per-unit (1000), --cycles 3.0+|2.8
  eevee     same as blender (EEVEE legacy ignores the albedo in its d: lossy)
  hdrp      --albedo (Base Color), --scattering-color, --multiplier (1), --world-scale (1 m), --mm-per-unit (1000)
  unreal    --albedo (Surface Albedo), --mfp-color, --mfp-distance (cm), --world-unit-scale (0.1), --mm-per-unit (10)
  jimenez   --albedo, --sss-width (scene units), --strength, --falloff, --samples (17), --mm-per-unit (1000)
--mm-per-unit is the scene unit in mm for both sides (default: each engine's usual unit). The JSON holds albedo,
burley.d_mm and the target's parameters by their UI names; see docs/engines.md for the formulas and sources.
"""

_ENGINES = ("sss_jax", "blender", "eevee", "hdrp", "unreal", "jimenez")
_DEFAULT_UNIT = {"sss_jax": 1.0, "blender": 1000.0, "eevee": 1000.0, "hdrp": 1000.0, "unreal": 10.0, "jimenez": 1000.0}


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "convert",
        help="convert a material between engines (Blender, EEVEE, HDRP, Unreal, separable SSS)",
        description="Convert a subsurface material from one engine's parameters to another's through the Burley "
        "profile they describe.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--from", dest="source", required=True, choices=_ENGINES, help="engine of the given parameters")
    p.add_argument("--to", dest="target", required=True, choices=_ENGINES, help="engine to convert to")
    p.add_argument("--albedo", type=rgb_triple, help="surface albedo R,G,B in [0,1] (each engine's colour input)")
    p.add_argument("--d-mm", type=rgb_triple, help="sss_jax: Burley d per channel, mm")
    p.add_argument("--mfp-mm", type=rgb_triple, help="sss_jax: mean free path per channel, mm (d = mfp / s(A))")
    p.add_argument("--radius", type=rgb_triple, help="blender/eevee: Subsurface Radius, scene units")
    p.add_argument("--scale", type=float, default=1.0, help="blender/eevee: Subsurface Scale (default 1)")
    p.add_argument("--cycles", choices=("3.0+", "2.8"), default="3.0+",
                   help="blender: Cycles version family (2.80-2.93 divide by s(A); default 3.0+)")
    p.add_argument("--scattering-color", type=rgb_triple, help="hdrp: Scattering Color (linear)")
    p.add_argument("--multiplier", type=float, default=1.0, help="hdrp: scattering distance Multiplier (default 1)")
    p.add_argument("--world-scale", type=float, default=1.0, help="hdrp: World Scale, metres per unit (default 1)")
    p.add_argument("--mfp-color", type=rgb_triple, help="unreal: Mean Free Path Color")
    p.add_argument("--mfp-distance", type=float, help="unreal: Mean Free Path Distance, cm")
    p.add_argument("--world-unit-scale", type=float, default=0.1, help="unreal: World Unit Scale (default 0.1)")
    p.add_argument("--sss-width", type=float, help="jimenez: sssWidth, scene units")
    p.add_argument("--strength", type=rgb_triple, help="jimenez: strength R,G,B in [0,1]")
    p.add_argument("--falloff", type=rgb_triple, help="jimenez: falloff R,G,B in [0,1]")
    p.add_argument("--samples", type=int, default=17, help="jimenez: kernel taps (default 17)")
    p.add_argument("--mm-per-unit", type=float, help="scene unit in mm (default: the engine's usual unit)")
    p.add_argument("--json", type=pathlib.Path, help="write the result as JSON here (default: print a table)")
    p.set_defaults(func=run)


def _need(args, name: str, engine: str, what: str):
    value = getattr(args, name)
    if value is None:
        raise ValueError(f"--from {engine} needs --{name.replace('_', '-')} {what}")
    return value


def _source_params(args) -> dict:
    src = args.source
    unit = args.mm_per_unit if args.mm_per_unit is not None else _DEFAULT_UNIT[src]
    albedo = _need(args, "albedo", src, "R,G,B")
    if src == "sss_jax":
        if (args.d_mm is None) == (args.mfp_mm is None):
            raise ValueError("--from sss_jax needs exactly one of --d-mm R,G,B or --mfp-mm R,G,B")
        if args.d_mm is not None:
            return {"albedo": albedo, "d_mm": args.d_mm}
        from .._engines import _rgb, _s

        mfp = _rgb("--mfp-mm", args.mfp_mm, lo=0.0)
        return {"albedo": albedo, "d_mm": (mfp / _s("diffuse_transmission", _rgb("--albedo", albedo))).tolist()}
    if src in ("blender", "eevee"):
        params = {"Subsurface Color": albedo, "Subsurface Radius": _need(args, "radius", src, "R,G,B"),
                  "Subsurface Scale": args.scale, "mm_per_unit": unit}
        if src == "blender":
            params["cycles"] = args.cycles
        return params
    if src == "hdrp":
        return {"Base Color": albedo, "Scattering Color": _need(args, "scattering_color", src, "R,G,B"),
                "Multiplier": args.multiplier, "World Scale": args.world_scale, "mm_per_unit": unit}
    if src == "unreal":
        return {"Surface Albedo": albedo, "Mean Free Path Color": _need(args, "mfp_color", src, "R,G,B"),
                "Mean Free Path Distance": _need(args, "mfp_distance", src, "CM"),
                "World Unit Scale": args.world_unit_scale, "mm_per_unit": unit}
    return {"albedo": albedo, "sssWidth": _need(args, "sss_width", src, "W"),
            "strength": _need(args, "strength", src, "R,G,B"), "falloff": _need(args, "falloff", src, "R,G,B"),
            "nSamples": args.samples, "mm_per_unit": unit}


def _target_options(args) -> dict:
    dst = args.target
    unit = args.mm_per_unit if args.mm_per_unit is not None else _DEFAULT_UNIT[dst]
    if dst == "sss_jax":
        return {}
    options: dict = {"mm_per_unit": unit}
    if dst == "blender":
        options.update(subsurface_scale=args.scale, cycles=args.cycles)
    elif dst == "eevee":
        options.update(subsurface_scale=args.scale)
    elif dst == "unreal":
        options.update(world_unit_scale=args.world_unit_scale)
    elif dst == "jimenez":
        options.update(n_samples=args.samples)
    return options


def _fmt(value) -> str:
    if isinstance(value, (list, tuple)):
        return ", ".join(_fmt(v) for v in value)
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, dict):
        return json.dumps(value)
    return str(value)


def _table(result: dict) -> str:
    rows = [("albedo", result["albedo"]), ("burley d (mm)", result["burley"]["d_mm"])]
    target = result[result["to"]]
    rows += [(f"{result['to']}: {k}", v) for k, v in target.items() if k != "fit"]
    if "fit" in target:
        rows.append((f"{result['to']}: fit error (rel. L2)", target["fit"]["error_relative_l2"]))
    if result.get("lossy"):
        rows.append(("lossy", result["lossy"]))
    width = max(len(k) for k, _ in rows)
    head = f"{result['from']} -> {result['to']}"
    return "\n".join([head, "-" * len(head)] + [f"{k:<{width}}  {_fmt(v)}" for k, v in rows])


def run(args) -> int:
    from .._engines import convert

    try:
        if args.mm_per_unit is not None and not (0 < args.mm_per_unit < float("inf")):
            raise ValueError(f"--mm-per-unit must be a finite positive number, got {args.mm_per_unit}")
        if args.json is not None and not args.json.parent.is_dir():
            raise ValueError(f"--json: directory {args.json.parent} does not exist")
        params = _source_params(args)
        result = convert(args.source, args.target, params, **_target_options(args))
    except ValueError as exc:
        print(f"sss-jax convert: {exc}", file=sys.stderr)
        return 2
    if args.json is not None:
        from .._io import write_json_atomic

        write_json_atomic(args.json, result)
        print(f"wrote {args.json}", file=sys.stderr)
    else:
        print(_table(result))
    return 0
