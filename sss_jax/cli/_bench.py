"""``sss-jax bench``: the measured speed/accuracy trade and the performance ratios."""

from __future__ import annotations

import argparse
import csv
import io
import pathlib
import sys

from ._options import (WarningPrinter, add_counts, add_technique_flags, comma_separated_counts,
                       comma_separated_names, option_arguments, technique_options)

EPILOG = """examples:
  sss-jax bench --quick                       # reduced grid, under two minutes on a 2-core CPU
                                              # (on a GPU: 256x256, 1920x1080 and 3840x2160, ratios at 1920x1080)
  sss-jax bench --json bench.json --out-dir bench_out   # full grid: table CSV, Pareto plot, JSON
  sss-jax bench --quick --technique separable --taps 9 --border leaves   # one configuration
  sss-jax bench --quick --technique hdrp,eevee-next,jimenez --quality high --frames 16 --taps 17

Without --technique the bench runs its grid (STA, separable at each --taps, Burley at each --samples) and the
performance goals at the defaults. With --technique it runs those techniques (the engines' passes too), each at
every --taps/--samples value where it has that option (else at the grid's counts of its count option, or once),
with the cost per pixel as its shader executes it on the demo frame, and its time against the peers (no goals).
Technique flags (--border, --pattern, --quality, ...) reach every technique of the run that has that option.
"""


def _registered() -> tuple[str, ...]:
    from .._techniques import TECHNIQUES

    return tuple(TECHNIQUES)


def _names(text: str) -> tuple[str, ...]:
    names, unknown = comma_separated_names(text, _registered())
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown technique(s) {', '.join(unknown)}; registered: "
                                         f"{', '.join(_registered())}")
    return names


# what the grid runs (the reference: the error columns)
GRID = ("sta", "separable", "burley", "reference")


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "bench",
        help="measure time, memory and error of every technique against peers",
        description="Time STA, separable (5..65 taps) and Burley (4..128 samples) at 256x256..1920x1080, with compile "
        "time, memory and the error against the reference; OpenCV sepFilter2D/filter2D and SciPy FFT convolution "
        "measured side by side; print the ratios against the performance goals.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--quick", action="store_true", help="reduced grid (ratios at 640x360)")
    p.add_argument("--json", type=pathlib.Path, help="write the whole result as JSON")
    p.add_argument("--out-dir", type=pathlib.Path, help="write table.csv and pareto.png here")
    p.add_argument("--repeats", type=int, help="timed runs per configuration, median (default 3; 2 with --quick)")
    p.add_argument("--technique", type=_names, metavar="NAME[,NAME...]",
                   help="bench these techniques instead of the grid (registered: " + ", ".join(_registered()) + ")")
    p.add_argument("--taps", type=comma_separated_counts, metavar="N[,N...]", help="taps to run, for every technique of the run with a "
                   "taps option (default: the grid's 5..65, 9,25 with --quick; jimenez: its own 17)")
    p.add_argument("--samples", type=comma_separated_counts, metavar="N[,N...]", help="samples to run, for every technique of the run "
                   "with a samples option (default: the grid's 4..128, 8,32 with --quick)")
    # the techniques' own options (the counts are the flags above)
    add_technique_flags(p, exclude=("samples", "taps", "radius_px", "albedo", "thickness"))
    p.set_defaults(func=run)


def _add_counts(args, options: dict, running) -> None:
    add_counts(args, options, running, "the techniques run")


def run(args) -> int:
    from .._bench import plot_pareto, run_bench
    from .._io import write_bytes_atomic, write_json_atomic

    from .._io import SSSInputError, check_output_folder, check_writable

    try:  # the outputs' places checked before the benchmark runs (a folder as --json failed at its end)
        if args.json is not None:
            check_writable(args.json, create_dirs=False)
        if args.out_dir is not None:
            check_output_folder(args.out_dir, "--out-dir")
    except SSSInputError as exc:
        print(f"sss-jax bench: {exc}", file=sys.stderr)
        return 2
    if args.repeats is None:
        args.repeats = 2 if args.quick else 3
    if args.repeats < 1:
        print("sss-jax bench: --repeats must be >= 1", file=sys.stderr)
        return 2
    try:
        running = (*args.technique, "reference") if args.technique else GRID
        options = {t: technique_options(args, t, others=running) for t in running}
        _add_counts(args, options, running)
        extra = option_arguments(run_bench, options, "bench")
        if args.technique:
            extra["techniques"] = list(args.technique)
        with WarningPrinter("sss-jax bench"):  # the techniques' warnings as every command says them
            result = run_bench(quick=args.quick, repeats=args.repeats,
                               progress=lambda m: print(m, file=sys.stderr, flush=True), **extra)
    except (ValueError, TypeError) as exc:
        print(f"sss-jax bench: {exc}", file=sys.stderr)
        return 2
    m = result["machine"]
    print(f"\nmachine: backend {m['backend']}, device {m['device']}, formulation {m['impl']}, jax {m['jax']}")
    print("cost per pixel as a shader runs it (texel fetches, flops: counted from the formulation, the same on any "
          "machine) beside the wall times of this one")
    names = [" ".join([r["technique"]] + [f"{k}={v}" for k, v in (r.get("options") or {}).items()])
             for r in result["rows"]]
    width = max([10] + [len(n) for n in names])
    print(f"{'technique':{width}s} {'n':>4s} {'size':>10s} {'ms/frame':>10s} {'fetches':>8s} {'flops':>7s} "
          f"{'compile s':>9s} {'rel L2 demo':>11s} {'edge':>7s} {'line':>7s} {'point':>7s}  pareto")
    for r, name in zip(result["rows"], names):
        e, c = r["errors"], r["cost_per_pixel"]
        print(f"{name:{width}s} {r['count'] or '':>4} {r['width']}x{r['height']:<5} {r['ms_per_frame']:10.2f} "
              f"{c['fetches']:8g} {c['flops']:7g} {r['compile_seconds']:9.2f} {e['demo']:11.4f} "
              f"{e['shadow_edge']:7.4f} {e['thin_line']:7.4f} {e['point_light']:7.4f}  {'*' if r['pareto'] else ''}")
    taa = sorted({int(r["cost_per_pixel"].get("frames", 1)) for r in result["rows"]} - {1})
    if taa:  # one call renders every TAA frame; the shader's counts are per frame
        print(f"(rows with frames {', '.join(map(str, taa))}: ms/frame is one call rendering all of them, fetches "
              "and flops are per frame)")
    w, h = result["ratio_resolution"]
    peers = ", ".join(f"{k} {v:.2f}" for k, v in result["peers_ms"].items()) or "none (OpenCV/SciPy absent)"
    print(f"\npeers at {w}x{h} (ms): {peers}")
    print(f"ratios at {w}x{h}:")
    for k, v in result["ratios"].items():
        met = "n/a" if v["met"] is None else ("met" if v["met"] else "NOT met")
        print(f"  {k:34s} {v['value']!s:>10}   goal {v['goal']:8s} {met}")
    for k, v in result.get("other_ratios", {}).items():
        print(f"  {k:34s} {v!s:>10}   (shown, no goal)")
    if result.get("footprint_skip"):
        print("footprint skip (pixels under half a pixel keep local shading), rel L2 against the reference:")
        for r in result["footprint_skip"]:
            print(f"  d x {r['d_scale']:<8.4g} skipped {100 * r['skipped_fraction']:5.1f}%   with skip "
                  f"{r['rel_l2_with_skip']:.4f}   without {r['rel_l2_without_skip']:.4f}")
    if args.json:
        write_json_atomic(args.json, result)
    if args.out_dir:
        args.out_dir.mkdir(parents=True, exist_ok=True)
        buf = io.StringIO()
        fields = ["technique", "count", "width", "height", "ms_per_frame", "fetches_per_pixel", "flops_per_pixel",
                  "compile_seconds", "error_demo", "peak_memory_vs_input", "pareto"]
        writer = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        writer.writerows({**r, "fetches_per_pixel": r["cost_per_pixel"]["fetches"],
                          "flops_per_pixel": r["cost_per_pixel"]["flops"]} for r in result["rows"])
        write_bytes_atomic(args.out_dir / "table.csv", buf.getvalue().encode())
        plot_pareto(result, args.out_dir / "pareto.png")
    return 0
