"""``sss-jax report``: how far each technique is from the reference and from an offline render, on the user's frames,
and what each costs."""

from __future__ import annotations

import argparse
import json
import pathlib
import shutil
import sys
import tempfile

from . import rgb_triple
from ._options import (WarningPrinter, add_camera_flags, add_counts, add_technique_flags, sta_thickness_warning,
                       technique_entries)
from ._options import add_sta_flags, comma_separated_counts, given_sta_flag_names, sta_params, technique_options

EPILOG = """examples:
  sss-jax report frame.exr --out rep --albedo 0.85,0.75,0.55 --d-mm 31.8,19.9,11.9
  sss-jax report irradiance_backlit.exr --out rep --truth burley_backlit.exr --truth-channels Combined \\
      --albedo 0.85,0.75,0.55 --d-mm 31.83,19.89,11.94 --techniques separable,burley --taps 9,25 --samples 8,32
  sss-jax report 'shots/*.exr' --out rep --preset skin1,marble --light-dir 0.3,-0.4,0.9
  sss-jax report frame.exr --out rep --truth cycles.exr --albedo 0.85,0.75,0.55 --d-mm 31.8,19.9,11.9 \\
      --techniques burley,hdrp:quality=low,hdrp:quality=high,eevee-next,jimenez --samples 32 --frames 16

The engines' own passes (hdrp, eevee-next, jimenez) run as each engine executes its pass; the summary gives each
run's cost per pixel as its shader executes it (samples, texels fetched, flops per SSS pixel and frame) beside the
time on this machine. Technique flags (--border, --quality, --frames, ...) reach every technique of the report
that has the option; an entry's own options (hdrp:quality=high) override them for that entry.

Frames are read as `sss-jax apply` reads them (R,G,B + Z, Blender multilayer passes, or --channel-map; camera from
the flags, the EXR header or a sidecar <name>.json). Several materials: --preset a,b,... (id k takes the k-th).
The dense reference is computed once per frame and kept in OUT/cache/ (a second run reads it back).
Writes OUT/report.html (one self-contained page), OUT/report.json and each compared image as
OUT/images/<frame>/<technique>_<count>.exr (linear RGB, float32).
"""


# technique options the report sets through flags of its own (the counts it sweeps, the reference's window, STA's
# albedo and thickness)
OWN_FLAGS = ("samples", "taps", "radius_px", "albedo", "thickness")
DEFAULT_TECHNIQUES = "sta,separable,burley"
DEFAULT_TAPS, DEFAULT_SAMPLES = (9, 17, 25), (8, 16, 32, 64)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "report",
        help="error report on your own frames: each technique against the reference and an offline render",
        description="Run STA, separable and Burley at several counts, and the engines' own passes (hdrp, "
        "eevee-next, jimenez) as the engines execute them, on EXR frames, compare them with the dense reference "
        "(cached) and, with --truth, with an offline render of the same view, and write a self-contained HTML report "
        "and its JSON, with each run's time here and its cost per pixel as its shader executes it.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("inputs", nargs="+", help="input EXR files or glob patterns")
    p.add_argument("--out", required=True, type=report_dir, help="output directory (created if missing)")
    p.add_argument("--truth", nargs="+", help="offline render(s) of the same view, one per input")
    p.add_argument("--truth-channels", help="truth pass (Blender: Combined, the default) or R,G,B channel names")
    from .._evaluate import REPORT_TECHNIQUES

    p.add_argument("--techniques", default=DEFAULT_TECHNIQUES, metavar="NAME[:OPTION=VALUE...],...",
                   help=f"comma-separated, from {', '.join(REPORT_TECHNIQUES)} (default {DEFAULT_TECHNIQUES}; sta "
                   "only with --light-dir); the engines' own passes are hdrp, eevee-next and jimenez; an entry may "
                   "carry options of its own, e.g. hdrp:quality=low,hdrp:quality=high,eevee-next:frames=64")
    p.add_argument("--taps", type=comma_separated_counts, default=None, help="taps to run: separable at each (default 9,17,25); "
                   "given, jimenez at each too (it takes 11, 17, 25; else its own 17)")
    p.add_argument("--samples", type=comma_separated_counts, default=None, help="Burley samples to run (default 8,16,32,64)")

    add_technique_flags(p, techniques=REPORT_TECHNIQUES, exclude=OWN_FLAGS)
    m = p.add_argument_group("material (as sss-jax apply)")
    m.add_argument("--preset", help="preset name(s) or JSON file(s), comma-separated: material id k takes the k-th")
    m.add_argument("--albedo", type=rgb_triple, help="surface albedo R,G,B in [0,1] (overrides an albedo pass)")
    m.add_argument("--d-mm", type=rgb_triple, help="Burley scattering distance d per channel, mm")
    m.add_argument("--mfp-mm", type=rgb_triple, help="mean free path per channel, mm")
    c = p.add_argument_group("camera and channels (as sss-jax apply)")
    add_camera_flags(c)
    c.add_argument("--radius-px", type=int, help="reference window radius in px (default: 99.9%% of the energy, at most 96 px)")
    c.add_argument("--repeats", type=int, default=3, help="timed runs per frame after compilation (default 3; 0: no timed run, the times are "
                   "the first, compiling run's and the report says so)")
    s = p.add_argument_group("STA (included with --light-dir)")
    s.add_argument("--light-dir", type=rgb_triple, help="direction towards the back light, camera space")
    s.add_argument("--light-colour", type=rgb_triple, default=(1.0, 1.0, 1.0))
    add_sta_flags(s, rgb_triple)
    s.add_argument("--thickness", type=float, help="constant thickness in scene units where there is no thickness channel")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--no-images", action="store_true", help="do not write OUT/images/<frame>/<technique>.exr")
    p.set_defaults(func=run)


def materials(args):
    """``(burley_material, separable_material, sta, info)`` from the flags, as ``apply`` reads them."""
    import jax.numpy as jnp
    import numpy as np

    from .._materials import BurleyMaterial, DirectionalLight, TwoGaussianMaterial
    from .._presets import load_preset

    given = [n for n in ("d_mm", "mfp_mm", "preset") if getattr(args, n) is not None]
    if len(given) > 1:
        raise ValueError("give either --preset or --d-mm/--mfp-mm, not both" if "preset" in given
                         else "give either --d-mm or --mfp-mm, not both")
    preset_sta, info = None, {}
    if args.preset is not None:
        presets = [load_preset(n.strip()) for n in args.preset.split(",") if n.strip()]
        if not presets:
            raise ValueError(f"--preset {args.preset!r} names no preset")
        albedo = [args.albedo or tuple(np.asarray(pr.burley.albedo).reshape(3)) for pr in presets]
        mat = BurleyMaterial(np.asarray(albedo, np.float32),
                             np.asarray([np.asarray(pr.burley.d_mm).reshape(3) for pr in presets], np.float32))
        sep = mat
        if all(pr.two_gaussian is not None for pr in presets):
            tgs = [pr.two_gaussian for pr in presets]
            field = lambda n: np.asarray([np.asarray(getattr(t, n)).reshape(3) for t in tgs], np.float32)
            sep = TwoGaussianMaterial(np.asarray(albedo, np.float32), field("w"), field("sigma_near_mm"),
                                      field("sigma_far_mm"))
        preset_sta = presets[0].sta
        info = {"source": "preset", "names": [pr.name for pr in presets], "preset_files": [pr.path for pr in presets]}
    else:
        albedo = args.albedo if args.albedo is not None else (1.0, 1.0, 1.0)
        if args.d_mm is not None:
            mat = BurleyMaterial(albedo, args.d_mm)
            info = {"source": "--d-mm"}
        elif args.mfp_mm is not None:
            mat = BurleyMaterial.from_mfp(albedo, args.mfp_mm)
            info = {"source": "--mfp-mm", "mfp_mm": list(args.mfp_mm)}
        else:
            raise ValueError("the report needs the material: --preset NAME, --d-mm R,G,B or --mfp-mm R,G,B")
        sep = mat
    sta = None
    given = given_sta_flag_names(args)
    if given and args.light_dir is None:
        raise ValueError(f"{', '.join(given)} set the STA row's parameters: the report includes STA with --light-dir")
    if args.light_dir is not None:
        # the preset's STA block (if any), each --sta-* given over it
        sta = (sta_params(args, preset_sta), DirectionalLight(jnp.asarray(args.light_dir, jnp.float32),
                                                              args.light_colour))
    return mat, sep, sta, info


def _runs(entries: list[tuple[str, dict]], args, sta) -> list:
    """What ``evaluate_frames`` runs for the ``--techniques`` entries: a name where nothing is given for it (the
    report builds it), else a technique object from the registry with the flags' options, the entry's own over
    them, and what it has fields for (the STA's light, thickness, albedo); jimenez (taps without a count sweep)
    once per ``--taps`` value where ``--taps`` is given."""
    import dataclasses

    from .._techniques import TECHNIQUES

    names = [n for n, _ in entries]
    # a count no technique of the report takes would do nothing: refused, as apply, bench and advise refuse it
    add_counts(args, {}, list(dict.fromkeys(names)), "the techniques run")
    flags = {n: technique_options(args, n, others=names) for n in dict.fromkeys(names)}
    runs = []
    for name, own in entries:
        cls = TECHNIQUES[name]
        fields = {f.name for f in dataclasses.fields(cls)}
        if cls.count_option is not None and cls.count_option in own:
            raise ValueError(f"--techniques {name}:{cls.count_option}=...: the report sweeps {name}'s "
                             f"{cls.count_option}; give them as --{cls.count_option}")
        options = {**flags[name], **own}
        context = {"light": None if sta is None else sta[1], "thickness": args.thickness, "albedo": args.albedo}
        extra = {k: v for k, v in context.items() if k in fields and v is not None and k not in options}
        counts = [{}]
        if cls.count_option is None and "taps" in fields and "taps" not in own and args.taps is not None:
            counts = [{"taps": n} for n in args.taps]
        if not options and counts == [{}]:
            runs.append(name)
            continue
        for count in counts:
            try:
                runs.append(cls(**extra, **options, **count))
            except ValueError as exc:
                flag = "--taps" if count else "--techniques/the technique flags"
                raise ValueError(f"{flag}: {exc}") from None
    return runs


def _warn_sta_thickness(args, params) -> None:
    """STA's thickness far outside its falloff on a frame (it would add nothing, or not depend on the thickness)."""
    import warnings

    from .._batch import expand_inputs
    from .._io import read_frame
    from .._materials import STAParams

    if not isinstance(params, STAParams):
        return
    for path in expand_inputs(args.inputs):
        try:
            frame = read_frame(path, channel_map=args.channel_map, focal_px=args.focal_px,
                               mm_per_unit=args.mm_per_unit, depth_kind=args.depth_kind)
        except (OSError, ValueError):
            continue  # evaluate_frames names it
        message = sta_thickness_warning(frame, params, args.thickness)
        if message:
            warnings.warn(f"{path}: {message}", UserWarning, stacklevel=2)


def report_dir(text: str) -> pathlib.Path:
    """A report folder option's type (``report --out``, ``fit --report``): a folder's path, not an empty string
    (which would be the current folder)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("empty: give the report's folder")
    return pathlib.Path(text)


def check_report_out(out: pathlib.Path, flag: str = "--out") -> None:
    """Before any work: ``out`` is a folder or can become one, and a file can be written where it goes (the report
    is staged beside it): a path under a file, a read-only place or a pseudo filesystem is refused now, not after
    the frames have been computed."""
    from .._io import check_output_folder

    check_output_folder(out, flag)
    for name in ("report.json", "report.html"):
        if (out / name).exists() and not _a_report(out):
            raise ValueError(f"{flag} {out} holds a {name} that is not an sss-jax report: the report would replace "
                             "it; give a new or empty folder, or the folder of an earlier report")


def _a_report(out: pathlib.Path) -> bool:
    """Whether ``out/report.json`` is one a report wrote (its top-level keys)."""
    import json

    try:
        doc = json.loads((out / "report.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and {"techniques", "local_shading", "machine"} <= set(doc)


def run(args) -> int:
    from .._evaluate import REPORT_TECHNIQUES, evaluate_frames
    from .._report import report

    try:
        entries = technique_entries(args.techniques, REPORT_TECHNIQUES)
        techniques = [n for n, _ in entries]
        for name in ("focal_px", "mm_per_unit"):
            v = getattr(args, name)
            if v is not None and not (0 < v < float("inf")):
                raise ValueError(f"--{name.replace('_', '-')} must be a finite positive number, got {v}")
        check_report_out(args.out)
        from .._batch import expand_inputs
        from .._report._layout import check_inputs_outside_images

        check_inputs_outside_images(args.out, [*expand_inputs(args.inputs), *(args.truth or [])])
        mat, sep, sta, info = materials(args)
        shown = WarningPrinter("sss-jax report")
        notes = []
        if "sta" in techniques and sta is None:
            if args.techniques != DEFAULT_TECHNIQUES:
                raise ValueError("--techniques sta needs --light-dir X,Y,Z (the back light's direction)")
            entries = [e for e in entries if e[0] != "sta"]
            techniques = [n for n, _ in entries]
            notes.append("STA left out: it needs the back light's direction (--light-dir X,Y,Z).")
        run_sta = "sta" in techniques
        sta_only = [f"--{n.replace('_', '-')}" for n in ("thickness", "light_dir") if getattr(args, n) is not None]
        if sta_only and not run_sta:  # STA's alone: said, as its --sta-* flags are, not dropped
            why = ("STA needs --light-dir X,Y,Z too" if notes else f"--techniques {args.techniques} runs no STA")
            raise ValueError(f"{', '.join(sta_only)}: for STA, and {why}")
        runs = _runs(entries, args, sta)
        # the reference cache lives in OUT/cache; on a first run it is built in a scratch folder and moved in only
        # when the report is complete, so bad input or an interruption leaves nothing in OUT
        cache = args.out / "cache"
        scratch = None if cache.is_dir() else pathlib.Path(tempfile.mkdtemp(prefix="sss-jax-report-"))
        try:
            with shown:
                if sta is not None and run_sta:
                    _warn_sta_thickness(args, sta[0])
                data = evaluate_frames(
                    args.inputs, mat, truth=args.truth, truth_channels=args.truth_channels, techniques=runs,
                    taps=args.taps or DEFAULT_TAPS, samples=args.samples or DEFAULT_SAMPLES, separable_material=sep,
                    sta=sta, sta_thickness=args.thickness,
                    focal_px=args.focal_px, mm_per_unit=args.mm_per_unit, channel_map=args.channel_map,
                    depth_kind=args.depth_kind, use_albedo_pass=args.albedo is None, radius_px=args.radius_px,
                    cache_dir=scratch or cache, repeats=args.repeats, material_info=info, progress=not args.no_progress)
            if notes:
                import dataclasses

                data = dataclasses.replace(data, notes=data.notes + tuple(notes))
            html = report(data, args.out, images=not args.no_images)
            if scratch is not None:
                cache.mkdir(parents=True, exist_ok=True)
                for item in scratch.iterdir():
                    shutil.move(str(item), str(cache / item.name))
        finally:
            if scratch is not None:
                shutil.rmtree(scratch, ignore_errors=True)
    except (ValueError, TypeError, OSError) as exc:
        print(f"sss-jax report: {exc}", file=sys.stderr)
        return 2
    rows = [(r.label, r.ms_per_frame) for r in data.runs]
    summary = json.loads((args.out / "report.json").read_text())
    errors = {e["label"]: e for e in summary["techniques"]}
    targets = [("vs_reference", "reference")] + ([("vs_truth", "truth")] if summary["local_shading"]["vs_truth"]
                                                  else [])

    def accuracy(e) -> str:  # the report's summary in one line: rel L2 and mean CIEDE2000 against each target
        return "; ".join(f"vs {what} rel L2 {e[k]['rel_l2']:.4f}, dE {e[k]['delta_e_mean']:.2f}" for k, what in targets)

    for r in data.runs:  # what each run costs as its shader executes it, beside the time here, and how wrong it is
        c = r.cost_per_pixel or {}
        cost = (f"; {c['samples']:g} samples, {c['fetches']:g} texels, {c['flops']:g} flops per SSS pixel and frame"
                if c else "")
        print(f"  {r.label}: {r.ms_per_frame:.1f} ms per frame here{cost}")
        print(f"    {accuracy(errors[r.label])}")
    print(f"  local shading (no SSS): {accuracy(summary['local_shading'])}")
    for note in notes:  # what the report left out and why (also in report.json's notes)
        print(f"sss-jax report: note: {note}", file=sys.stderr)
    print(f"report: {html}")
    print(f"{len(rows)} technique runs on {len(data.frames)} frame(s); json: {args.out / 'report.json'}")
    return 0
