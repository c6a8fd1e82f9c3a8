"""``sss-jax advise``: the cheapest technique and sample count within a ΔE budget, from the measured trade."""

from __future__ import annotations

import argparse
import pathlib
import sys

from . import rgb_triple
from ._options import (WarningPrinter, add_camera_flags, add_counts, add_technique_flags, comma_separated_counts,
                       comma_separated_names, option_arguments, technique_options)

# the techniques whose counts the advisor weighs by default (beside local shading)
ADVISED = ("separable", "burley")
# what the advisor never weighs: the reference is what it measures against; the STA adds light (no Burley material)
NOT_ADVISED = ("reference", "sta")

EPILOG = """examples:
  sss-jax advise --material skin --max-delta-e 1.0
  sss-jax advise --material marble --scene demo --scene-scale 4 --size 128x96 --max-delta-e 0.5 --json advice.json
  sss-jax advise --material demo_skin --max-delta-e 1.0        # the demo scene's own skin (not the preset skin)
  sss-jax advise --material skin --max-delta-e 1 --technique burley,hdrp,eevee-next,jimenez --samples 8,32 \\
      --quality high --frames 16 --border leaves                # the engines' passes beside Burley, their options
  sss-jax advise --frame irradiance_backlit.exr --truth burley_backlit.exr --albedo 0.85,0.75,0.55 \\
      --d-mm 31.83,19.89,11.94 --max-delta-e 2                  # your frame, errors against its offline render

Candidates: local shading, then each --technique at each --taps/--samples value where it has that option (default:
separable 5,9,17,25 taps, Burley 4,8,16,32,64 samples), an engine's pass once with its options. Technique flags
(--border, --pattern, --quality, --frames, ...) reach every candidate that has that option (and the reference,
where it has it). With --truth the errors are against the offline render, not the reference; any candidate worse
than local shading is flagged either way.
"""


# the fewest timings whose interquartile range says something about the noise (``choose``'s ties)
_TIE_REPEATS = 3


def _size(text: str) -> tuple[int, int]:
    """WIDTHxHEIGHT, as ``sss-jax demo`` takes it (its bounds: 100000x100000 ran out of memory here); returns
    (height, width)."""
    from ._demo import _parse_size

    try:
        w, h = _parse_size(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return h, w


def _advisable() -> tuple[str, ...]:
    from .._techniques import TECHNIQUES

    return tuple(n for n in TECHNIQUES if n not in NOT_ADVISED)


def _names(text: str) -> tuple[str, ...]:
    names, bad = comma_separated_names(text, _advisable())
    if bad:
        raise argparse.ArgumentTypeError(f"{', '.join(bad)}: the advisor weighs {', '.join(_advisable())}")
    return names


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "advise",
        help="pick the cheapest technique and sample count whose error stays within a dE2000 budget",
        description="Run local shading, separable (5..25 taps) and Burley (4..64 samples), or the techniques of "
        "--technique (the engines' passes among them), on the scene made of the material or on your frame, time each "
        "on this machine (repeated: median and interquartile range), measure the mean CIEDE2000 against the "
        "reference (or the offline render of --truth), and pick the fastest within --max-delta-e; where the fastest "
        "one's timings overlap another's within the budget (within the noise), say so and pick the more accurate. "
        "Prints the table and the reason; flags any candidate worse than local shading.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    mat = p.add_argument_group("material (one of --material or --d-mm)")
    mat.add_argument("--material", help="a demo material (demo_skin, demo_marble, demo_wax) or a preset name or file")
    mat.add_argument("--d-mm", type=rgb_triple, help="Burley scattering distance d per channel, mm (with --albedo)")
    mat.add_argument("--albedo", type=rgb_triple, help="surface albedo R,G,B in [0, 1] with --d-mm (default 1,1,1)")
    p.add_argument("--scene", default=None, choices=["demo"], help="the scene measured on (default: demo)")
    p.add_argument("--scene-scale", type=float, default=None,
                   help="size of the scene's objects relative to the demo's (scales mm per scene unit; default 1)")
    p.add_argument("--size", type=_size, default=None, help="scene size WIDTHxHEIGHT in pixels, as `sss-jax demo` "
                   "takes it (default 96x72, cheap)")
    fr = p.add_argument_group("your frame instead of the demo scene (read as `sss-jax apply` reads it)")
    fr.add_argument("--frame", type=pathlib.Path, metavar="IN.exr", help="the frame's buffers (irradiance, depth, ...)")
    fr.add_argument("--truth", type=pathlib.Path, metavar="TRUTH.exr", help="an offline render of --frame's view: "
                    "the errors are against it instead of the reference")
    fr.add_argument("--truth-channels", help="truth pass (Blender: Combined, the default) or R,G,B channel names")
    add_camera_flags(fr)
    p.add_argument("--max-delta-e", type=float, required=True, help="budget: mean CIEDE2000 against the reference "
                   "(or the truth)")
    p.add_argument("--repeats", type=int, default=5,
                   help="timed runs per candidate: median and interquartile range; candidates whose ranges overlap "
                   "are within the noise and the more accurate one is preferred (default 5)")
    p.add_argument("--json", type=pathlib.Path, help="write the table and the choice as JSON")
    p.add_argument("--technique", type=_names, metavar="NAME[,NAME...]",
                   help="the techniques to weigh (default separable,burley; also " + ", ".join(
                       n for n in _advisable() if n not in ADVISED) + ")")
    p.add_argument("--taps", type=comma_separated_counts, metavar="N[,N...]",
                   help="taps to weigh, for every candidate with a taps option (default separable 5,9,17,25; "
                   "jimenez its own 17)")
    p.add_argument("--samples", type=comma_separated_counts, metavar="N[,N...]",
                   help="samples to weigh, for every candidate with a samples option (default 4,8,16,32,64)")
    # the candidates' own options (their counts are the flags above)
    add_technique_flags(p, exclude=("samples", "taps", "radius_px", "albedo", "thickness"))
    p.set_defaults(func=run)


def _material(args):
    """The advisor's material: ``--material`` (a name) or ``--d-mm`` with ``--albedo``."""
    from .._advise import resolve_material
    from .._materials import BurleyMaterial

    if args.material is not None and args.d_mm is not None:
        raise ValueError("give either --material or --d-mm (with --albedo), not both")
    if args.d_mm is not None:
        return BurleyMaterial(args.albedo if args.albedo is not None else (1.0, 1.0, 1.0), args.d_mm)
    if args.albedo is not None:
        raise ValueError("--albedo goes with --d-mm (a --material has its own albedo)")
    if args.material is None:
        raise ValueError("the advisor needs the material: --material NAME, or --d-mm R,G,B (with --albedo R,G,B)")
    resolve_material(args.material)  # an unknown name is an error here, listing the known ones
    return args.material


def _frame(args, material):
    """``{buffers, camera, truth}`` for ``advise`` from ``--frame``/``--truth``; {} for the demo scene."""

    if args.frame is None:
        if args.truth is not None:
            raise ValueError("--truth needs --frame IN.exr: the buffers of the view the truth renders")
        for flag in ("focal_px", "mm_per_unit", "channel_map", "truth_channels"):
            if getattr(args, flag) is not None:
                raise ValueError(f"--{flag.replace('_', '-')} reads --frame: give --frame IN.exr too")
        if args.depth_kind != "planar":
            raise ValueError(f"--depth-kind {args.depth_kind} reads --frame: give --frame IN.exr too")
        return {}
    for flag, value in (("--scene", args.scene), ("--scene-scale", args.scene_scale), ("--size", args.size)):
        if value is not None:
            raise ValueError(f"{flag} is for the demo scene; with --frame the frame and its camera are measured "
                             "(--mm-per-unit sets its scale)")
    from .._evaluate import read_truth
    from .._io import no_focal_length, read_frame

    for name in ("focal_px", "mm_per_unit"):
        v = getattr(args, name)
        if v is not None and not (0 < v < float("inf")):
            raise ValueError(f"--{name.replace('_', '-')} must be a finite positive number, got {v}")
    f = read_frame(args.frame, channel_map=args.channel_map, focal_px=args.focal_px, mm_per_unit=args.mm_per_unit,
                   depth_kind=args.depth_kind)
    if f.focal_px is None:
        raise no_focal_length(args.frame)
    # the frame's albedo pass where it has one and no --albedo overrides it
    buffers = f.to_buffers(use_albedo=args.albedo is None)
    out = {"buffers": buffers, "camera": f.camera()}
    if args.truth is not None:
        out["truth"] = read_truth(args.truth, args.truth_channels, frame=f)
    return out


def _counts(args, options: dict, running) -> None:
    add_counts(args, options, running, "the candidates")


def run(args) -> int:
    from .._io import SSSInputError

    try:
        with WarningPrinter("sss-jax advise"):  # the frame's and the techniques' warnings, as report says them
            advice, frame, size = _advise(args)
    except (ValueError, TypeError, OSError, SSSInputError) as exc:
        print(f"sss-jax advise: {exc}", file=sys.stderr)
        return 2
    if args.frame is not None:
        h, w = frame["buffers"].depth.shape
        where = f"frame {args.frame.name} {w}x{h}" + (f", against the truth {args.truth.name}" if args.truth else "")
    else:
        h, w = size
        where = f"scene {args.scene or 'demo'} {w}x{h} x{args.scene_scale or 1.0:g}"
    print(f"material {advice.material}, {where}, budget mean dE2000 <= {args.max_delta_e:g}")
    print(advice.table())
    if args.repeats < _TIE_REPEATS and advice.choice is not None:
        # an interquartile range of one or two timings is their spread at most: candidates that differ by the
        # machine's noise are not seen to tie, and the choice can change from one run to the next
        print(f"note: --repeats {args.repeats} times each candidate {'once' if args.repeats == 1 else 'twice'}: too few "
              "to tell a real difference in time from noise, so the choice may differ between runs; "
              f"--repeats {_TIE_REPEATS} or more (the default 5) shows which candidates tie", file=sys.stderr)
    if args.json:
        from .._io import write_json_atomic

        write_json_atomic(args.json, {**advice.to_json(), "frame": None if args.frame is None else str(args.frame),
                                      "truth": None if args.truth is None else str(args.truth)})
    return 0 if advice.choice is not None else 1


def _advise(args):
    """The advice, the frame's buffers (with --frame) and the scene's size: what ``run`` prints."""
    from .._advise import advise
    from .._io import check_writable

    if not (args.max_delta_e >= 0):
        raise ValueError(f"--max-delta-e must be >= 0, got {args.max_delta_e}")
    if args.scene_scale is not None and not (0 < args.scene_scale < float("inf")):
        raise ValueError(f"--scene-scale must be a finite positive number, got {args.scene_scale}")
    if args.repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {args.repeats}")
    if args.json is not None:
        check_writable(args.json, create_dirs=False)
    material = _material(args)
    frame = _frame(args, material)
    names = args.technique or ADVISED
    running = (*names, "reference")
    options = {t: technique_options(args, t, others=running) for t in running}
    _counts(args, options, names)
    extra = option_arguments(advise, options, "advise")
    if args.technique or args.taps or args.samples:
        extra["techniques"] = list(names)
    size = args.size or (72, 96)
    advice = advise(material, max_delta_e=args.max_delta_e, size=size, scene_scale=args.scene_scale or 1.0,
                    repeats=args.repeats, progress=lambda m: print(m, file=sys.stderr, flush=True),
                    **frame, **extra)
    return advice, frame, size
