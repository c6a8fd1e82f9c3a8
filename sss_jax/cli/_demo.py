"""``sss-jax demo``: the built-in scene with every technique, images and a report."""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

EPILOG = """example:
  sss-jax demo --out demo_out                 # 256x192, every technique, EXR + PNG + report.html
  sss-jax demo --out demo_out --size 512x384 --samples 64 --taps 33
"""


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo",
        help="render the built-in procedural scene with every technique",
        description="Render the procedural demo scene (two spheres and a thin back-lit slab over a ground plane) with "
        "STA, separable, Burley and the dense reference; write EXR and PNG images, a side-by-side overview, "
        "print time and error per technique, and write the HTML report.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", required=True, type=pathlib.Path, help="output directory (created if missing)")
    p.add_argument("--size", default="256x192", help="WIDTHxHEIGHT in pixels (default 256x192)")
    p.add_argument("--samples", type=int, default=32, help="Burley spiral samples (default 32)")
    p.add_argument("--taps", type=int, default=25, help="separable taps per pass (default 25)")
    p.add_argument("--no-report", action="store_true", help="skip the HTML report")
    p.add_argument("--overwrite", action="store_true", help="write into a folder that holds images, JSON or HTML "
                   "the demo did not make (refused otherwise: the demo would replace them)")
    p.set_defaults(func=run)


MADE_BY = "sss-jax demo"
# what the demo writes into --out besides <technique>.exr/.png: a folder holding one of these, or any image, that a
# demo did not make is the user's
_DEMO_FILES = ("summary.json", "overview.png", "report.html", "report.json", "images")


def _made_by_demo(out: pathlib.Path) -> bool:
    """Whether ``out`` holds a demo's output: its summary.json is the demo's (``made_by``; a summary of the demo's
    shape, width + height + rows, from a version before the marker)."""
    import json

    try:
        summary = json.loads((out / "summary.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(summary, dict) and (summary.get("made_by") == MADE_BY
                                          or {"width", "height", "rows"} <= set(summary))


def _check_out(out: pathlib.Path, *, overwrite: bool) -> None:
    """Refuse an --out that is a file, or a folder with images, JSON or HTML of the user's that the demo would
    replace (issue #30: the demo silently overwrote a user's reference.exr and summary.json)."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is an existing file, not a folder: the demo writes a folder of images and a "
                         "report; give a new or empty folder")
    if not out.is_dir() or overwrite or _made_by_demo(out):
        return
    theirs = sorted(p.name for p in out.iterdir()
                    if p.name in _DEMO_FILES or p.suffix.lower() in (".exr", ".png", ".html", ".json"))
    if theirs:
        shown = ", ".join(theirs[:6]) + (f" and {len(theirs) - 6} more" if len(theirs) > 6 else "")
        raise ValueError(f"--out {out} holds files a demo did not make ({shown}) that the demo could replace; "
                         "give a new or empty folder, or pass --overwrite")


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size must look like 256x192, got {text!r}") from None
    if w < 8 or h < 8 or w > 8192 or h > 8192:
        raise ValueError(f"--size must be between 8x8 and 8192x8192, got {text!r}")
    return w, h


def run(args) -> int:
    from .._demo import run_demo, summary_rows
    from .._io import (
        check_output_folder,
        write_exr,
        write_json_atomic,
        write_png_preview,
    )

    try:
        width, height = _parse_size(args.size)
        if args.samples < 1:
            raise ValueError(f"--samples must be >= 1, got {args.samples}")
        if args.taps < 1 or args.taps % 2 == 0:
            raise ValueError(f"--taps must be an odd number >= 1, got {args.taps}")
        out = args.out
        _check_out(out, overwrite=args.overwrite)
        # before any work: a folder that exists but takes no file (read-only, a pseudo filesystem) failed only
        # when the first image was written, after the rendering, with a traceback
        check_output_folder(out, "--out")
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ValueError(f"--out {out}: cannot create the folder ({exc.strerror})") from None
    except (ValueError, OSError) as exc:
        print(f"sss-jax demo: {exc}", file=sys.stderr)
        return 2

    from ._options import WarningPrinter

    with WarningPrinter("sss-jax demo"):  # the passes' warnings as apply and report say them, once each
        t0 = time.perf_counter()
        result = run_demo(height=height, width=width, samples=args.samples, taps=args.taps,
                          progress=lambda msg: print(msg, file=sys.stderr, flush=True))
        for name, img in result.images.items():
            write_exr(out / f"{name}.exr", img.astype("float32"), attributes={"sss_jax:technique": name})
            write_png_preview(out / f"{name}.png", img)
        _write_overview(out / "overview.png", result)
        rows = summary_rows(result)
        write_json_atomic(out / "summary.json", {"made_by": MADE_BY, "width": width, "height": height, "rows": rows})
        print(f"\n{'technique':34s} {'ms/frame':>9s} {'rel L2 vs ref':>14s}  energy out/in (R, G, B)")
        for r in rows:
            ms = "" if r["ms_per_frame"] is None else f"{r['ms_per_frame']:9.1f}"
            print(f"{r['technique']:34s} {ms:>9s} {r['rel_l2_vs_reference']:14.4f}  "
                  + ", ".join(f"{x:.3f}" for x in r["energy_ratio_rgb"]))
        print("(STA adds light: its energy ratio exceeds 1 by design; separable and Burley redistribute it.)")
        if not args.no_report:
            from .._demo import demo_montecarlo, demo_trade
            from .._reporting import write_demo_report

            print("timing the trade (STA, separable 9/17/25, burley 8/16/32/64) and the Monte Carlo profiles ...",
                  file=sys.stderr, flush=True)
            html = write_demo_report(result, out, trade=demo_trade(result), montecarlo=demo_montecarlo())
            print(f"report: {html}")
    print(f"wrote {out}/ in {time.perf_counter() - t0:.1f} s")
    return 0


def _write_overview(path: pathlib.Path, result) -> None:
    """A labelled grid of the renders, for a person to look at first."""
    from .._io import write_bytes_atomic
    from .._report import figure_png, new_figure

    names = [n for n in ("irradiance", "local", "sta") if n in result.images] + [
        n for n in result.images if n not in ("irradiance", "local", "sta")
    ]
    cols = 4
    rows = (len(names) + cols - 1) // cols
    h, w = result.images[names[0]].shape[:2]
    fig = new_figure(cols * 3.2, rows * 3.2 * h / w + 0.4 * rows, dpi=110)
    for i, name in enumerate(names):
        ax = fig.add_subplot(rows, cols, i + 1)
        img = result.images[name]
        disp = np.clip(img, 0, 1) ** (1 / 2.2)
        ax.imshow(disp, interpolation="nearest")
        err = result.errors.get(name)
        ax.set_title(name if err is None else f"{name}\nrel L2 {err:.3f}", fontsize=8)
        ax.axis("off")
    fig.tight_layout()
    write_bytes_atomic(path, figure_png(fig))

