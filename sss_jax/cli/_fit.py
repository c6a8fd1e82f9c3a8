"""``sss-jax fit``: presets (``fits/<material>.json``) for measured and artist materials; with ``--render``, a
technique's material matched to a path-traced render of the same view (``sss_jax._match``)."""

from __future__ import annotations

import argparse
import pathlib
import sys

from . import rgb_triple
from ._options import add_sta_flags, add_technique_flags, given_sta_flag_names, given_technique_options
from ._options import add_camera_flags, option_arguments, technique_options
from ._report import check_report_out, report_dir

# the techniques `fit --render` matches
MATCHED = ("burley", "separable", "sta")

EPILOG = """examples:
  sss-jax fit --all                                   # every measured and artist material into fits/
  sss-jax fit --material skin --material marble --out my_fits
  sss-jax fit --name velvet_wax --albedo 0.9,0.7,0.5 --d-mm 3,2,1.2 --out my_fits
  sss-jax fit --list
  sss-jax fit --render white.exr --truth cycles.exr --technique burley --albedo 0.85,0.75,0.55 --d-mm 30,20,12 --json fit.json --html fit.html

Measured materials come from Jensen et al. 2001, Table 2 (or --measured-csv with the same columns); artist materials
are surface albedo and Burley d per channel. Each preset holds Burley d, the two-Gaussian kernel (fitted as separable
renders it: the product a(x) a(y), pixel-integrated), the STA parameters, the slab transmittance of its own medium
(sss-jax transmit), their errors against Burley and Monte Carlo, the fit records, engine parameters and HLSL/GLSL
taps; see fits/README.md.
Monte Carlo runs are cached in OUT/montecarlo and reused when photons, seed and version match.

With --render (repeatable, one --truth per --render) the command matches instead: per material id it fits Burley d
(burley), the two-Gaussian kernel (separable) or the STA parameters (sta), starting from the material given as
`apply` takes it (--preset, --albedo with --d-mm/--mfp-mm, STA flags), so the technique at --samples/--taps
looks like the offline render on the material's pixels; --holdout IN TRUTH frames are measured, not fitted.
--json, --html and --report are refused before the fit where one would write over an input (a frame, a truth, a
sidecar, the channel map) or over another of them. See docs/match.md.
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
    p.add_argument("--albedo", type=rgb_triple, help="new artist material (or with --render: the starting material): "
                   "surface albedo R,G,B in (0,1)")
    p.add_argument("--d-mm", type=rgb_triple, help="new artist material (or with --render: the starting material): "
                   "Burley d R,G,B in mm")
    p.add_argument("--out", type=pathlib.Path, default=pathlib.Path("fits"), help="output directory (default fits)")
    p.add_argument("--photons", type=int, default=None, help="Monte Carlo photons per channel (default 100000)")
    p.add_argument("--seed", type=int, default=0, help="Monte Carlo seed (default 0)")
    p.add_argument("--solver", choices=("optimistix", "jaxopt"), default="optimistix", help="least-squares solver")
    p.add_argument("--taps", type=int, default=25, help="taps of the exported HLSL/GLSL kernel; with --render, the "
                   "separable technique's taps the fit is for (default 25)")
    p.add_argument("--measured-csv", type=pathlib.Path, help="measured coefficients (default: Jensen et al. 2001)")
    p.add_argument("--no-plots", action="store_true", help="skip the per-preset plots")
    _register_match(p)
    p.set_defaults(func=run)
    p.set_defaults(fit_defaults=vars(p.parse_args([])))  # what each flag is when not given (_given)


# the flags of one mode only: making presets, or matching a render (--render); given in the other they would do
# nothing (the technique options and the STA flags are checked on their own)
PRESET_ONLY = ("out", "photons", "seed", "solver", "measured_csv", "no_plots")
MATCH_ONLY = ("samples", "mfp_mm", "preset", "fit_albedo", "loss", "huber_delta", "max_steps", "score",
              "held_fraction", "focal_px", "mm_per_unit", "depth_kind", "channel_map", "truth_channels", "json", "html",
              "report", "radius_px", "light_dir", "light_colour", "thickness")


def _given(args, dests) -> list[str]:
    """The flags among ``dests`` given with a value other than their default, as typed."""
    defaults = args.fit_defaults
    return ["--" + d.replace("_", "-") for d in dests if getattr(args, d) != defaults.get(d)]


def run(args) -> int:
    if args.render is not None or args.truth is not None or args.holdout is not None:
        return _run_match(args)
    if given_technique_options(args):
        flags = ", ".join("--" + args.technique_flag_names.get(k, k).replace("_", "-")
                          for k in given_technique_options(args))
        print(f"sss-jax fit: {flags}: technique options are for matching a render (--render); presets are fitted "
              "to profiles", file=sys.stderr)
        return 2
    match_only = _given(args, MATCH_ONLY) + given_sta_flag_names(args)
    if args.technique is not None:
        match_only.insert(0, "--technique")
    if match_only:
        print(f"sss-jax fit: {', '.join(match_only)}: for matching a render (--render IN.exr --truth TRUTH.exr); "
              "making presets does not read them", file=sys.stderr)
        return 2
    from .._fit_presets import (
        ARTIST_MATERIALS,
        DEFAULT_PHOTONS,
        LEAST_PHOTONS,
        check_preset_name,
        fit_presets,
        measured_materials,
    )
    from .._io import SSSInputError, check_output_folder

    try:
        measured = measured_materials(args.measured_csv)
        if args.list:
            print("measured:", ", ".join(sorted(measured)))
            print("artist:  ", ", ".join(sorted(ARTIST_MATERIALS)))
            return 0
        photons = DEFAULT_PHOTONS if args.photons is None else args.photons
        if photons < 1:
            raise ValueError(f"--photons must be a positive integer, got {photons}")
        if photons < LEAST_PHOTONS:
            raise ValueError(f"--photons must be at least {LEAST_PHOTONS} (the medium's slabs run a tenth each, "
                             f"and a Monte Carlo run needs 2), got {photons}")
        if not 0 <= args.seed < 2**32:  # checked here, not after the first material's walks have begun
            raise ValueError(f"--seed must be an integer in [0, 2**32), got {args.seed}")
        if args.taps < 1:
            raise ValueError(f"--taps must be a positive integer, got {args.taps}")
        if args.taps % 2 == 0:
            raise ValueError(f"--taps must be odd (the exported kernel has a centre tap), got {args.taps}")
        custom = [args.name, args.albedo, args.d_mm]
        artist = None
        if any(v is not None for v in custom):
            if any(v is None for v in custom):
                raise ValueError("a new artist material needs all of --name, --albedo R,G,B and --d-mm R,G,B")
            if args.name in measured or args.name in ARTIST_MATERIALS:
                raise ValueError(f"--name {args.name!r} is a built-in material; choose another name")
            check_preset_name(args.name)
            artist = {args.name: {"albedo": list(args.albedo), "d_mm": list(args.d_mm)}}
        names = args.material if args.material else ([] if artist and not args.all else None)
        check_output_folder(args.out, "--out")
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


# ------------------------------------------------------------------------------------------------------------------
# match mode: sss-jax fit --render IN.exr --truth TRUTH.exr --technique burley|separable|sta
# ------------------------------------------------------------------------------------------------------------------


def _register_match(p) -> None:
    m = p.add_argument_group("match a path-traced render (--render; the material flags as `apply` takes them)")
    m.add_argument("--render", action="append", type=pathlib.Path, metavar="IN.exr",
                   help="the technique's input frame (repeatable: several frames of one shot are fitted at once)")
    m.add_argument("--truth", action="append", type=pathlib.Path, metavar="TRUTH.exr",
                   help="the offline render of the same view, one per --render (Blender's Combined pass, else R,G,B)")
    m.add_argument("--holdout", nargs=2, action="append", type=pathlib.Path, metavar=("IN.exr", "TRUTH.exr"),
                   help="a frame and its truth measured before and after but not fitted (repeatable)")
    m.add_argument("--truth-channels", help="the truth's pass (e.g. Combined) or three channels R,G,B")
    m.add_argument("--technique", choices=MATCHED, help="the technique to match")
    m.add_argument("--samples", type=int, default=32, help="Burley spiral samples the fit is for (default 32)")
    m.add_argument("--mfp-mm", type=rgb_triple, help="starting mean free path per channel, mm (d = mfp / s(A))")
    m.add_argument("--preset", help="starting material: a preset name or JSON file")
    m.add_argument("--fit-albedo", action="store_true", help="fit the albedo too (the albedo pass is not used)")
    m.add_argument("--loss", choices=("huber", "l2"), default="huber",
                   help="huber (default: robust to path-tracing noise) or l2 (plain rel_l2)")
    m.add_argument("--huber-delta", type=float, default=0.5,
                   help="Huber threshold in units of the material's mean truth value (default 0.5)")
    m.add_argument("--max-steps", type=int, default=20, help="Levenberg-Marquardt steps at most (default 20)")
    m.add_argument("--score", choices=("held", "all"), default="held",
                   help="pixels the fit scores: held (default: those whose starting kernel the frame holds, so d is "
                        "not bent to make up for light beyond the frame) or all SSS pixels")
    m.add_argument("--held-fraction", type=float, default=0.95,
                   help="with --score held: the share of the kernel's energy inside the frame a scored pixel needs "
                        "(default 0.95)")
    add_camera_flags(m)
    m.add_argument("--json", type=pathlib.Path, metavar="OUT.json", help="write the result as JSON")
    m.add_argument("--html", type=pathlib.Path, metavar="OUT.html",
                   help="write a standalone HTML page: before/after renders, error maps, fitted parameters")
    m.add_argument("--report", type=report_dir, metavar="DIR",
                   help="also write the error report (as `sss-jax report` does) of the fitted material on these "
                        "frames against the reference and the truth, with a section showing the fit's before/after "
                        "and the fitted parameters (burley and separable)")
    m.add_argument("--radius-px", type=int, metavar="N", help="the report's reference window radius in px (default: "
                   "the radius holding 99.9%% of the profile's energy, at most 96 px)")
    sta = p.add_argument_group("STA start (with --render --technique sta)")
    sta.add_argument("--light-dir", type=rgb_triple, help="direction towards the light, camera space")
    sta.add_argument("--light-colour", type=rgb_triple, default=(1.0, 1.0, 1.0))
    add_sta_flags(sta, rgb_triple)
    sta.add_argument("--thickness", type=float, help="constant thickness in scene units where frames carry none")
    # the matched technique's own options (--seed is the Monte Carlo's here: Burley's is --burley-seed)
    add_technique_flags(p, techniques=MATCHED, exclude=("samples", "taps", "radius_px", "albedo", "thickness"),
                        rename={"seed": "burley-seed"}, title="technique options (with --render)")


def _check_outputs_apart(args) -> None:
    """--json, --html and the report's files are files of their own, none of them an input (a render, a truth, a
    held-back frame, a render's sidecar, the channel map): ``check_writable`` says only that a path can be written."""
    from .._io import SSSInputError, output_problems

    writes = [(flag, path) for flag, path in (("--json", args.json), ("--html", args.html)) if path is not None]
    if args.report is not None:
        writes += [("--report", args.report / name) for name in ("report.json", "report.html")]
    frames = [*(args.render or []), *(args.truth or []), *(p for pair in (args.holdout or []) for p in pair)]
    inputs = frames + [p.with_suffix(".json") for p in frames if p.with_suffix(".json").is_file()]
    if args.channel_map is not None and pathlib.Path(args.channel_map).is_file():
        inputs.append(pathlib.Path(args.channel_map))
    problems = output_problems(writes, inputs)
    if problems:
        raise SSSInputError("; ".join(problems))


def _run_match(args) -> int:
    from .._checks import check_host_count
    from .._io import SSSInputError, check_writable, write_json_atomic
    from .._match import load_match_frame, match_render, write_match_html
    from ._apply import _material

    try:
        if args.all or args.material or args.list or args.name is not None:
            raise ValueError("--render matches a render; --all, --material, --list and --name make presets: "
                             "give one or the other")
        preset_only = _given(args, PRESET_ONLY)
        if preset_only:
            raise ValueError(f"{', '.join(preset_only)}: for making presets; matching a render (--render) does not "
                             "read them (its solver is optimistix's Levenberg-Marquardt; Burley's seed is "
                             "--burley-seed; --json/--html/--report name its outputs)")
        renders, truths = args.render or [], args.truth or []
        if not renders or len(renders) != len(truths):
            raise ValueError(f"give one --truth per --render: got {len(renders)} --render and {len(truths)} --truth")
        if args.technique is None:
            raise ValueError("--render needs --technique burley, separable or sta")
        for name in ("samples", "taps", "max_steps"):
            if getattr(args, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
        if args.taps % 2 == 0:
            raise ValueError(f"--taps must be odd, got {args.taps}")
        for name in ("focal_px", "mm_per_unit", "huber_delta"):
            v = getattr(args, name)
            if v is not None and not (v > 0 and v < float("inf")):
                raise ValueError(f"--{name.replace('_', '-')} must be a finite positive number, got {v}")
        options = technique_options(args, args.technique)
        model = options.get("model", "sta")
        if args.technique == "sta" and model != "sta":
            raise ValueError(f"--model {model}: the match fits the STA parameters of --model sta; the {model} model "
                             "has none to fit (its light follows the medium: a preset's, or the Burley medium of "
                             "--albedo/--d-mm), so `apply --technique sta --model "
                             f"{model}` renders it as it is")
        material, light = _material(args)  # the starting material, exactly as `apply` reads it
        extra = option_arguments(match_render, {args.technique: options}, "fit --render")
        if args.technique == "sta":
            material = (material, args.albedo if args.albedo is not None else (1.0, 1.0, 1.0))
        use_albedo_pass = args.albedo is None and not args.fit_albedo
        read = lambda r, t: load_match_frame(r, t, truth_channels=args.truth_channels, channel_map=args.channel_map,
                                             focal_px=args.focal_px, mm_per_unit=args.mm_per_unit,
                                             depth_kind=args.depth_kind, use_albedo_pass=use_albedo_pass)
        frames = [read(r, t) for r, t in zip(renders, truths)]
        holdout = [read(r, t) for r, t in (args.holdout or [])]
        for out in (args.json, args.html):  # before the fit: a folder, a path under a file, a read-only folder
            if out is not None:
                check_writable(out)
        _check_outputs_apart(args)
        if args.report is not None:  # a path under a file, a read-only place, another's report.json: now
            check_report_out(args.report, "--report")
        if args.report is not None and args.technique == "sta":
            raise ValueError("--report needs --technique burley or separable (the report's reference is a profile)")
        if args.report is not None and args.radius_px is not None:  # the report's, checked before the fit
            check_host_count(args.radius_px, "--radius-px")
        result = match_render(frames, material, technique=args.technique, holdout=holdout, samples=args.samples,
                              taps=args.taps, light=light, thickness=args.thickness, fit_albedo=args.fit_albedo,
                              loss=args.loss, huber_delta=args.huber_delta, max_steps=args.max_steps,
                              score=args.score, held_fraction=args.held_fraction, **extra)
    except (ValueError, TypeError, OSError, SSSInputError) as exc:
        print(f"sss-jax fit: {exc}", file=sys.stderr)
        return 2
    data = result.to_json()
    data["inputs"] = {"render": [str(r) for r in renders], "truth": [str(t) for t in truths],
                      "holdout": [[str(r), str(t)] for r, t in (args.holdout or [])],
                      "truth_channels": args.truth_channels,
                      "camera": [{"frame": f.name, "focal_px": float(f.camera.focal_px),
                                  "mm_per_unit": float(f.camera.mm_per_unit)} for f in frames + holdout],
                      "albedo_from": "albedo pass" if use_albedo_pass else "material"}
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        write_json_atomic(args.json, data)
    if args.html is not None:
        args.html.parent.mkdir(parents=True, exist_ok=True)
        write_match_html(args.html, result)
    if args.report is not None:
        _match_report(args, result, material, use_albedo_pass, options)
    e = result.errors
    s = result.solver
    print(f"{args.technique}: {s['result']} after {s['iterations']} iterations ({s['seconds']:.1f} s); "
          f"rel_l2 on fitted frames {e['fitted']['before']['pooled']['all']:.4f} -> "
          f"{e['fitted']['after']['pooled']['all']:.4f}"
          + ("" if e["holdout"] is None else f", held back {e['holdout']['before']['pooled']['all']:.4f} -> "
             f"{e['holdout']['after']['pooled']['all']:.4f}"))
    sc = result.scored
    fitted = [f for f in sc["frames"] if f["role"] == "fitted"]
    print(f"  scored {sum(f['scored_pixels'] for f in fitted)} of {sum(f['sss_pixels'] for f in fitted)} "
          f"SSS pixels ({sc['rule']}); rel_l2 on them {e['fitted']['scored']['before']['pooled']['all']:.4f} -> "
          f"{e['fitted']['scored']['after']['pooled']['all']:.4f}")
    for k, params in result.parameters.items():
        print(f"  {k}: " + "; ".join(f"{n} = {', '.join(f'{v:.4g}' for v in (x if isinstance(x, list) else [x]))}"
                                     for n, x in params.items()))
    if result.options.get("albedo_from", "material") != "material":
        print("  (albedo: the frames' albedo pass rendered them, and `apply` without --albedo uses it the same way; "
              "the albedo shown is its mean over each id's pixels)")
    if "max_steps" in s["result"]:  # the result string alone said it: a fit cut short read as a converged one
        print(f"sss-jax fit: warning: the solver stopped at --max-steps {args.max_steps} before it converged; the "
              "parameters above are where it stopped (more steps may lower the error further)", file=sys.stderr)
    return 0


def _match_report(args, result, start, use_albedo_pass: bool, options: dict) -> None:
    """The report of the fitted material on the fitted frames (``sj.evaluate_frames`` measures, ``sj.report`` lays
    out), with the fit's own section: the report and the match share one page. The report runs the technique with
    the options the fit ran it with (``--border``, ``--pattern``, ...; it ran the defaults' before: its row and the
    fit's section disagreed)."""
    from .._evaluate import evaluate_frames
    from .._match import match_report_html
    from .._report import report
    from .._techniques import get_technique

    cls = get_technique(args.technique)
    fitted = cls(**{k: v for k, v in options.items() if k != cls.count_option})
    burley_fit = args.technique == "burley"
    data = evaluate_frames(args.render, result.material if burley_fit else start, truth=args.truth,
                           truth_channels=args.truth_channels, techniques=[fitted], samples=[args.samples],
                           taps=[args.taps], separable_material=None if burley_fit else result.material,
                           focal_px=args.focal_px, mm_per_unit=args.mm_per_unit, channel_map=args.channel_map,
                           depth_kind=args.depth_kind, use_albedo_pass=use_albedo_pass, radius_px=args.radius_px,
                           cache_dir=args.report / "cache", repeats=1, progress=True)
    report(data, args.report, extra_sections=[("Match to the truth render", match_report_html(result))])
    print(f"wrote {args.report / 'report.html'}")
