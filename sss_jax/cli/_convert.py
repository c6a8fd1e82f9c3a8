"""``sss-jax convert``: one material in another engine's units. Flags, their help and the dispatch come from the
engine registry (``sss_jax.engines``): a new engine brings its own flags."""

from __future__ import annotations

import argparse
import json
import pathlib
import sys

from . import rgb_triple, srgb_colour

EPILOG = """examples:
  sss-jax convert --from sss_jax --to blender --albedo 0.8,0.6,0.5 --d-mm 3,1.4,0.8 --method random-walk
  sss-jax convert --from blender --to eevee-next --albedo 0.8,0.5,0.4 --radius 1,0.2,0.1 --scale 0.5
  sss-jax convert --from blender --to unreal --albedo 0.8,0.6,0.5 --radius 1,0.2,0.1 --scale 0.05 --json ue.json
  sss-jax convert --from hdrp --to eevee --albedo 0.8,0.6,0.5 --scattering-color-srgb 0.9,0.6,0.5 --multiplier 4
  sss-jax convert --from sss_jax --to jimenez --albedo 0.8,0.6,0.5 --mfp-mm 8,4,2 --json jimenez.json

Parameters per engine (all lengths per channel as R,G,B; one number means all three):
{engines}
--mm-per-unit is the scene unit in mm for both sides (default: each engine's usual unit). A flag that is both a
parameter of the source and an option of the target (--blender-version, --method, --scale, --mm-per-unit, ...)
sets both; --to-<flag> sets the target's alone, e.g. a Blender 2.93 material in Blender 4.2:
  sss-jax convert --from blender --to blender --albedo 0.8,0.6,0.5 --radius 1,0.2,0.1 --blender-version 2.93 \\
    --to-blender-version 4.2 --to-method random-walk
The JSON holds albedo, burley.d_mm, the target's parameters by their UI names, what is lossy or unverified, and the
sources each conversion was read from; docs/engines.md has the formulas.
"""

_TYPES = {"rgb": rgb_triple, "srgb": srgb_colour, "float": float, "int": int, "str": str}


def _registry():
    from ..engines import REGISTRY

    return REGISTRY


def _flags() -> dict:
    """Every engine's flags, once each (engines that share a flag share its meaning and kind)."""
    flags: dict = {}
    for engine in _registry().values():
        for f in engine.flags:
            seen = flags.get(f.flag)
            if seen is not None and (seen.kind, seen.choices) != (f.kind, f.choices):
                raise RuntimeError(f"engines disagree on {f.flag}: {seen.kind} vs {f.kind}")
            flags.setdefault(f.flag, f)
    return flags


def _both_ways() -> list:
    """The flags that are both a source's parameter and a target's option: each gets a ``--to-`` twin that sets the
    target's option alone (the plain flag then sets the source's parameter alone)."""
    return [f for f in _flags().values() if f.key is not None and f.option is not None]


def _engine_lines() -> str:
    width = max(len(n) for n in _registry())
    return "\n".join(f"  {name:<{width}}  " + ", ".join(f.flag + (" (required)" if f.required else "")
                                                       for f in e.flags if f.flag != "--mm-per-unit")
                     for name, e in _registry().items())


def register(subparsers) -> None:
    names = tuple(_registry())
    p = subparsers.add_parser(
        "convert",
        help="convert a material between engines (Cycles, EEVEE, EEVEE Next, HDRP, Unreal, separable SSS)",
        description="Convert a subsurface material from one engine's parameters to another's through the Burley "
        "profile they describe.",
        epilog=EPILOG.format(engines=_engine_lines()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--from", dest="source", required=True, choices=names, help="engine of the given parameters")
    p.add_argument("--to", dest="target", required=True, choices=names, help="engine to convert to")
    for f in _flags().values():
        p.add_argument(f.flag, dest=f.dest, type=_TYPES[f.kind], choices=f.choices, metavar=f.metavar, help=f.help)
    for f in _both_ways():
        p.add_argument("--to-" + f.flag[2:], dest="to_" + f.dest, type=_TYPES[f.kind], choices=f.choices,
                       metavar=f.metavar, help=f"the target's {f.flag[2:]} where it differs from the source's "
                       f"(default: {f.flag}'s value)")
    p.add_argument("--json", type=pathlib.Path, help="also write the result as JSON here (the table is printed either way)")
    p.set_defaults(func=run)


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
    rows += [(f"{result['to']}: {k}", v) for k, v in target.items() if k not in ("fit", "unverified")]
    if "fit" in target:
        rows.append((f"{result['to']}: fit error (rel. L2)", target["fit"]["error_relative_l2"]))
    for note in ("note", "lossy", "unverified"):
        if result.get(note):
            rows.append((note.upper() if note == "unverified" else note, result[note]))
    width = max(len(k) for k, _ in rows)
    head = f"{result['from']} -> {result['to']}"
    return "\n".join([head, "-" * len(head)] + [f"{k:<{width}}  {_fmt(v)}" for k, v in rows])


def run(args) -> int:
    from ..engines import convert

    registry = _registry()
    values = vars(args)
    source, target = registry[args.source], registry[args.target]
    params_of = {f.dest for f in source.flags if f.key is not None}  # what --from reads, what --to takes
    options_of = {f.dest for f in target.flags if f.option is not None}
    both_ways = _both_ways()
    try:
        if args.mm_per_unit is not None and not (0 < args.mm_per_unit < float("inf")):
            raise ValueError(f"--mm-per-unit must be a finite positive number, got {args.mm_per_unit}")
        if args.json is not None:  # a folder, a path under a file, a read-only place: refused now, not at the write
            if not args.json.parent.is_dir():
                raise ValueError(f"--json: directory {args.json.parent} does not exist")
            from .._io import check_writable

            check_writable(args.json, create_dirs=False)
        ignored = [f.flag for f in _flags().values() if values.get(f.dest) is not None
                   and f.dest not in params_of | options_of]
        if ignored:  # a flag neither engine of this conversion reads would be dropped without a word
            raise ValueError(f"{', '.join(ignored)}: not a parameter of {args.source} (--from) nor an option of "
                             f"{args.target} (--to); `sss-jax convert --help` lists each engine's flags")
        ignored = ["--to-" + f.flag[2:] for f in both_ways
                   if values.get("to_" + f.dest) is not None and f.dest not in options_of]
        if ignored:
            raise ValueError(f"{', '.join(ignored)}: not an option of {args.target} (--to); "
                             "`sss-jax convert --help` lists each engine's flags")
        params = source.params_from_flags(values)
        # the target's options: a --to- flag where given, else the plain flag's value (both sides alike)
        targeted = {**values, **{f.dest: values["to_" + f.dest] for f in both_ways
                                 if values.get("to_" + f.dest) is not None}}
        result = convert(args.source, args.target, params, **target.options_from_flags(targeted))
    except ValueError as exc:
        # a plain flag the message names set both sides: say how to set the target's alone (e.g. a legacy EEVEE
        # 4.1 material to EEVEE Next, which starts with 4.2)
        both = [f.flag for f in both_ways if values.get(f.dest) is not None and values.get("to_" + f.dest) is None
                and f.dest in str(exc) and f.dest in params_of & options_of]
        hint = "".join(f" ({flag} set both --from and --to; --to-{flag[2:]} sets the target's alone)" for flag in both)
        print(f"sss-jax convert: {exc}{hint}", file=sys.stderr)
        return 2
    print(_table(result))  # the table always; the JSON as well where asked
    if args.json is not None:
        from .._io import write_json_atomic

        write_json_atomic(args.json, result)
        print(f"wrote {args.json}", file=sys.stderr)
    return 0
