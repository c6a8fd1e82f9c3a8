"""``sss-jax apply``: run a technique over one frame or many."""

from __future__ import annotations

import argparse
import pathlib
import sys

from . import rgb_triple
from ._options import (WarningPrinter, add_camera_flags, add_technique_flags, given_technique_options,
                       sta_thickness_warning)
from ._options import add_sta_flags, check_option_taken, given_sta_flag_names, sta_params, technique_options

EPILOG = """examples:
  sss-jax apply frame.exr -o out.exr --technique burley --albedo 0.8,0.6,0.5 --d-mm 3,1.4,0.8 --focal-px 1200 --mm-per-unit 10
  sss-jax apply render.exr -o sss.exr --technique separable --albedo 0.85,0.75,0.55 --mfp-mm 400,250,150
  sss-jax apply 'shots/*.exr' --out-dir sss/ --technique burley --albedo 0.8,0.6,0.5 --d-mm 3,1.4,0.8 --png
  sss-jax apply frame.exr -o sta.exr --technique sta --albedo 0.8,0.6,0.5 --light-dir -0.25,0.3,0.9 --thickness 0.5 --mm-per-unit 10 --sta-thickness-mm 4,2.5,1.5
  sss-jax apply frame.exr -o skin.exr --technique separable --preset my_skin.json --focal-px 1200
  sss-jax apply 'shots/*/beauty.exr' --out-dir sss/ --technique burley --preset skin --resume

Outputs: --out-dir keeps each input's path below the inputs' common folder (shots/a/beauty.exr ->
sss/a/beauty.exr), so inputs of one name never share an output; sss/sss_jax_manifest.json lists every frame's
input, output, status (done, failed with the message, skipped, pending) and seconds, kept true on Ctrl-C. Before
any frame runs, the batch is refused (exit 2, nothing written) when two inputs would write one output, an output is
an input, an existing output was made from another input (--overwrite allows it), or a folder is not writable.
--resume skips frames whose output is complete and was made from the same input (path, size, mtime) with the same
technique, parameters, sss_jax version and reading of the files (recorded in its EXR header). Frames larger than a tile's budget run in
tiles overlapping by the kernel's reach (same result); sample or tap counts beyond the footprint's pixels are
clamped with a warning.

Input channels: R,G,B irradiance and Z planar depth (scene units; inf = no surface); optional albedo.R/G/B, N.X/Y/Z,
thickness, id (0 = no SSS: passes through untouched). A Blender multi-layer EXR works as it is (DiffDir + DiffInd,
Depth, DiffCol, IndexOB); --albedo overrides the albedo pass. The focal length and scene unit come from the flags,
the EXR header (sss_jax:focal_px, sss_jax:mm_per_unit) or a sidecar <name>.json (camera.focal_px, or Blender's
camera.lens_mm and sensor_width_mm; scene_unit_mm); a Blender file without a unit is read in metres (with a warning),
any other in millimetres.
"""


# technique options that apply sets through flags of its own (--samples, --taps, --radius-px; STA's --albedo and
# --thickness, which also stand for the frame's albedo and thickness)
OWN_FLAGS = ("samples", "taps", "radius_px", "albedo", "thickness")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "apply",
        help="apply a technique to EXR frames",
        description="Apply STA, separable, Burley, the reference or an engine's own pass (hdrp, eevee-next, jimenez) to one or more EXR frames.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("inputs", nargs="+", help="input EXR files or glob patterns")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("-o", "--output", type=pathlib.Path, help="output EXR (one input; must end in .exr)")
    where.add_argument("--out-dir", type=pathlib.Path, help="output directory: each output is named after its input")
    p.add_argument("--technique", required=True, help="sta, separable, burley, reference, hdrp, eevee-next or jimenez")
    p.add_argument("--albedo", type=rgb_triple, help="surface albedo R,G,B in [0,1] (overrides an albedo pass)")
    p.add_argument("--d-mm", type=rgb_triple, help="Burley scattering distance d per channel, mm")
    p.add_argument("--mfp-mm", type=rgb_triple, help="mean free path per channel, mm (d = mfp / s(A), diffuse-transmission fit)")
    p.add_argument("--preset", help="material preset: a name (fits/<name>.json, or a directory in SSS_JAX_PRESETS) "
                   "or a preset JSON file")
    add_camera_flags(p)
    p.add_argument("--samples", type=int, default=None, help="Burley spiral samples (default 32)")
    p.add_argument("--taps", type=int, default=None,
                   help="taps per pass (default: the technique's own, separable 25, jimenez 17)")
    p.add_argument("--radius-px", type=int, help="reference window radius in pixels (default: 99.9%% of the energy, at most 96 px)")
    sta = p.add_argument_group("STA")
    sta.add_argument("--light-dir", type=rgb_triple, help="direction towards the light, camera space (x right, y down, z forward)")
    sta.add_argument("--light-colour", type=rgb_triple, default=(1.0, 1.0, 1.0), help="light irradiance R,G,B (default 1)")
    add_sta_flags(sta, rgb_triple)
    sta.add_argument("--thickness", type=float, help="constant thickness in scene units where there is no thickness channel")
    # every other option of the techniques, with the techniques' own help (--border, --pattern, --frames, ...)
    add_technique_flags(p, exclude=OWN_FLAGS)
    p.add_argument("--tile-pixels", type=int, help="pixels per tile at most: a larger frame runs in tiles overlapping "
                   "by the technique's reach (default: the batch's budget)")
    p.add_argument("--half", action="store_true", help="write half-float EXR")
    p.add_argument("--png", action="store_true", help="also write an sRGB PNG preview beside each output")
    p.add_argument("--resume", action="store_true", help="skip frames whose output is complete and was made from the "
                   "same input with the same technique, parameters and version")
    p.add_argument("--overwrite", action="store_true", help="allow replacing existing outputs made from other inputs")
    p.set_defaults(func=run)


def _material(args):
    import jax.numpy as jnp

    from .._materials import BurleyMaterial, DirectionalLight
    from .._presets import load_preset, material_for

    given = [n for n in ("d_mm", "mfp_mm", "preset") if getattr(args, n) is not None]
    if len(given) > 1:
        if "preset" in given:
            raise ValueError("give either --preset or --d-mm/--mfp-mm, not both")
        raise ValueError("give either --d-mm or --mfp-mm, not both")
    preset = load_preset(args.preset) if args.preset is not None else None
    albedo = args.albedo if args.albedo is not None else (1.0, 1.0, 1.0)
    sta_given = given_sta_flag_names(args)
    model = given_technique_options(args).get("model", "sta")
    if sta_given and (args.technique != "sta" or model != "sta"):  # given, they would be dropped: say so
        raise ValueError(f"{', '.join(sta_given)} set the STA model's parameters: give them with --technique sta "
                         "(--model sta)")
    if args.light_dir is not None and args.technique != "sta":
        raise ValueError(f"--light-dir is the back light of --technique sta; {args.technique} does not take it")
    if args.technique == "sta":
        if args.light_dir is None:
            raise ValueError("--technique sta needs --light-dir X,Y,Z")
        light = DirectionalLight(jnp.asarray(args.light_dir, jnp.float32), args.light_colour)
        if model != "sta":  # the physically based back-light models take the medium's scattering distance
            if preset is not None:
                # what the library gives this model: the preset's measured medium for 'slab' where it has one (its
                # boundaries and phase function), else its Burley material
                from .._techniques import Translucency

                tech = Translucency(light=light, model=model)
                material = material_for(tech, preset)
                if args.albedo is not None:
                    if not isinstance(material, BurleyMaterial):
                        raise ValueError(f"--albedo does not apply to {args.preset}'s measured medium (--model {model} "
                                         "takes it whole); give --d-mm or --mfp-mm with --albedo instead")
                    material = material_for(tech, preset, albedo=args.albedo)
                return material, light
            if args.d_mm is not None:
                return BurleyMaterial(albedo, args.d_mm), light
            if args.mfp_mm is not None:
                return BurleyMaterial.from_mfp(albedo, args.mfp_mm), light
            raise ValueError(f"--technique sta --model {model} needs the medium: --d-mm R,G,B, --mfp-mm R,G,B or "
                             "--preset")
        if args.d_mm is not None or args.mfp_mm is not None:  # the STA model has no scattering distance
            raise ValueError("--technique sta (--model sta) takes the STA parameters (--sta-*, or a --preset's), "
                             "not --d-mm/--mfp-mm (the slab and thin models take those: --model slab)")
        # a preset's STA block, each --sta-* given over it
        return sta_params(args, material_for("sta", preset) if preset is not None else None), light
    if preset is not None:
        return material_for(args.technique, preset, albedo=args.albedo), None
    if args.d_mm is not None:
        return BurleyMaterial(albedo, args.d_mm), None
    if args.mfp_mm is not None:
        return BurleyMaterial.from_mfp(albedo, args.mfp_mm), None
    raise ValueError(f"--technique {args.technique} needs the material: --d-mm R,G,B, --mfp-mm R,G,B or --preset")


def run(args) -> int:
    import dataclasses

    from .._techniques import TECHNIQUES, get_technique

    try:
        if args.technique not in TECHNIQUES:
            raise ValueError(f"unknown technique {args.technique!r}; valid techniques: {', '.join(TECHNIQUES)}")
        # a count the technique does not have is refused, as every other technique flag is (before: --samples
        # with separable, --taps with burley ran without a word)
        # a count left out is the technique's own default (jimenez's 17 taps, not separable's 25)
        own = {f.name: f.default for f in dataclasses.fields(get_technique(args.technique))}
        for name, default in (("samples", 32), ("taps", 25), ("radius_px", None)):
            if getattr(args, name) is not None:
                check_option_taken("--" + name.replace("_", "-"), name, (args.technique,))
            else:
                setattr(args, name, own.get(name, default))
        for name in ("samples", "taps"):
            if getattr(args, name) < 1:
                raise ValueError(f"--{name} must be >= 1, got {getattr(args, name)}")
        if args.taps % 2 == 0:
            raise ValueError(f"--taps must be odd, got {args.taps}")
        for name in ("focal_px", "mm_per_unit"):
            v = getattr(args, name)
            if v is not None and not (v > 0 and v < float("inf")):
                raise ValueError(f"--{name.replace('_', '-')} must be a finite positive number, got {v}")
        from .._batch import expand_inputs

        inputs = expand_inputs(args.inputs)
        if args.output is not None and len(inputs) != 1:
            raise ValueError(f"-o takes one input, got {len(inputs)}: use --out-dir for many")
        sta = args.technique == "sta"
        if args.output is not None and args.output.suffix.lower() != ".exr":
            raise ValueError(f"-o {args.output}: the output is a linear float EXR and needs the .exr extension "
                             "(--png adds an sRGB PNG preview beside it)")
        # STA takes --albedo as it is (the materials of the other techniques check their own)
        if sta and args.albedo is not None and not all(0.0 <= a <= 1.0 for a in args.albedo):  # NaN fails too
            raise ValueError(f"--albedo must be 3 values in [0, 1], got {','.join(map(str, args.albedo))}")
        if args.thickness is not None and not (args.thickness >= 0):
            raise ValueError(f"--thickness must be >= 0 scene units, got {args.thickness}")
        if args.tile_pixels is not None and args.tile_pixels < 1:
            raise ValueError(f"--tile-pixels must be >= 1, got {args.tile_pixels}")
        if args.radius_px is not None and args.radius_px < 0:
            raise ValueError(f"--radius-px must be >= 0, got {args.radius_px}")
        material, light = _material(args)
        options = technique_options(args, args.technique)
    except (ValueError, OSError) as exc:
        print(f"sss-jax apply: {exc}", file=sys.stderr)
        return 2

    from .._batch import process_frames

    shown = WarningPrinter("sss-jax apply")

    def report(r):
        if r.status == "failed":
            line = r.failure_line()
        elif r.status == "skipped":
            line = f"{r.input} -> {r.output} (skipped: {r.message})"
        else:
            said = r.message and (r.message in shown or f"{r.input}: {r.message}" in shown)
            line = f"{r.input} -> {r.output} ({r.seconds:.2f} s)" + (f"; {r.message}" if r.message and not said
                                                                    else "")
        print(line, file=sys.stderr)

    try:
        with shown:
            if args.technique == "reference" and args.radius_px is None:
                args.radius_px = _reference_radius(inputs, args, material)
            result = _run_batch(process_frames, inputs, args, options, material, light, report)
    except KeyboardInterrupt as exc:
        code = 128 + getattr(exc, "signum", 2)
        where = f"; {args.out_dir / 'sss_jax_manifest.json'} lists the finished frames" if args.out_dir else ""
        print(f"sss-jax apply: interrupted: only complete frames were written{where}", file=sys.stderr)
        return code
    except (ValueError, TypeError, OSError) as exc:
        print(f"sss-jax apply: {exc}", file=sys.stderr)
        return 2
    if result.failed:
        print(f"sss-jax apply: {len(result.failed)} of {len(result.frames)} frame(s) failed: "
              + "; ".join(f.input for f in result.failed), file=sys.stderr)
        return 1
    skipped = sum(f.status == "skipped" for f in result.frames)
    if skipped:
        print(f"sss-jax apply: {skipped} of {len(result.frames)} frame(s) skipped (--resume: already complete)",
              file=sys.stderr)
    return 0


def _run_batch(process_frames, inputs, args, options, material, light, report):
    """``process_frames`` with the technique as it takes it: the name, the counts and every other option given
    (``technique_options``); a technique object built from the registry (``technique(name, **options)``) for a batch
    that takes only objects; for a batch that takes only a name and its counts, the other options are refused (it
    cannot pass them on) and the technique's own warnings are computed here (it runs the frames traced)."""
    import inspect

    from .._techniques import TECHNIQUES

    accepted = inspect.signature(process_frames).parameters
    counts = {"samples": args.samples, "taps": args.taps, "radius_px": args.radius_px}
    common = dict(
        out_dir=args.out_dir, outputs=None if args.output is None else [args.output], png=args.png,
        focal_px=args.focal_px, mm_per_unit=args.mm_per_unit, channel_map=args.channel_map,
        depth_kind=args.depth_kind, use_albedo_pass=args.albedo is None, half=args.half, resume=args.resume,
        overwrite=args.overwrite, progress=len(inputs) > 1 or sys.stderr.isatty(), on_frame_done=report)
    if not common["progress"]:  # no bars: a long frame's progress as lines (the batch says how far, how long left)
        common["on_progress"] = lambda text: print(f"sss-jax apply: {text}", file=sys.stderr, flush=True)
    if args.tile_pixels is not None:
        common["tile_pixels"] = args.tile_pixels
    common = {k: v for k, v in common.items() if k in accepted}
    named = material if light is None else (material, light)
    # the counts (their defaults) go to the technique that has them; --albedo and --thickness are the frame's for
    # every technique and STA's options as well: passed on as STA's only to STA (a batch warns of one its technique
    # lacks)
    takes = {f.name for f in TECHNIQUES[args.technique].option_fields()}
    counts = {k: v for k, v in counts.items() if k in takes}
    sta = {"sta_albedo": args.albedo if "albedo" in takes else None,
           "sta_thickness": args.thickness if "thickness" in takes else None}
    if "technique_options" in accepted:  # it computes the technique's warnings for every frame itself
        _check_frames(inputs, args, material, light, counts, technique_checks=False)
        return process_frames(inputs, args.technique, named, technique_options=options, **sta, **counts, **common)
    if "Technique" in str(accepted["technique"].annotation):
        from .._techniques import technique

        own = dict(counts, albedo=args.albedo, thickness=args.thickness)
        options = {**{k: v for k, v in own.items() if k in takes and v is not None}, **options}
        _check_frames(inputs, args, material, light, counts, technique_checks=False)
        return process_frames(inputs, technique(args.technique, **({"light": light} if light is not None else {}),
                                                **options), material, **common)
    if options:
        raise ValueError(f"{', '.join('--' + k.replace('_', '-') for k in options)}: this version's batch takes a "
                         "technique's name and its counts only, not its other options")
    _check_frames(inputs, args, material, light, counts, technique_checks=True)
    return process_frames(inputs, args.technique, named, **sta, **counts, **common)


def _check_frames(inputs, args, material, light, counts, *, technique_checks: bool) -> None:
    """Warnings about each readable frame before the batch runs: STA's thickness where it makes the back light
    vanish (or not matter), and, for a batch that does not compute them (it runs the frames traced), the technique's
    own sampling and window warnings (``check`` of the technique object on the frame's buffers)."""
    import warnings

    from .._io import read_frame
    from .._materials import STAParams
    from .._techniques import TECHNIQUES

    cls = TECHNIQUES[args.technique]
    technique_checks = technique_checks and hasattr(cls, "check") and hasattr(cls, "option_fields")
    thickness_check = isinstance(material, STAParams)
    if not (technique_checks or thickness_check):
        return
    tech = None
    if technique_checks:
        from .._techniques import technique

        fields = {f.name for f in cls.option_fields()}
        tech = technique(args.technique, **({"light": light} if light is not None else {}),
                         **{k: v for k, v in counts.items() if k in fields and v is not None})
    for path in inputs:
        try:
            f = read_frame(path, channel_map=args.channel_map, focal_px=args.focal_px, mm_per_unit=args.mm_per_unit,
                           depth_kind=args.depth_kind)
        except (OSError, ValueError):
            continue  # reported when the batch reaches it
        if thickness_check:
            message = sta_thickness_warning(f, material, args.thickness)
            if message:
                warnings.warn(f"{path}: {message}", UserWarning, stacklevel=2)
        if tech is not None and f.focal_px is not None:
            cam = f.camera()
            for w in tech.check(f.to_buffers(use_albedo=args.albedo is None), material, cam):
                warnings.warn(f"{path}: {w}", type(w), stacklevel=2)


def _reference_radius(inputs, args, material) -> int:
    """One reference window for the whole sequence: the largest any readable frame needs."""
    from .._io import read_frame
    from .._techniques import reference_radius_px

    radius = 1
    for path in inputs:
        try:
            f = read_frame(path, channel_map=args.channel_map, focal_px=args.focal_px, mm_per_unit=args.mm_per_unit,
                           depth_kind=args.depth_kind)
        except (OSError, ValueError):
            continue  # reported when the batch reaches it
        if f.focal_px is not None:
            cam = f.camera()
            radius = max(radius, reference_radius_px(f.to_buffers(), material, cam))
    return radius
