"""Fitting Burley's d to a path-traced render: the held pixels scored against the whole frame, next to the true d.

    nice -n 10 .venv/bin/python scripts/held_scoring.py [--samples 32] [--max-steps 12] [--start 1.0]
        [--held-fraction 0.95] [--frames skin_closeup,blender] [--borders renormalise,leaves] [--json OUT]

For each frame (the Cycles render of ../shared/reference/blender and ours in tests/data/cycles, ``cycles_closeup``,
``cycles_grazing``, ``cycles_far``, whose true d is Cycles' own radius / (4 pi); the
Mitsuba skin close-up cut by the frame on every side, tests/data/mitsuba, whose true d is the Burley d fitted to the
index-matched medium's Monte Carlo profile, in its sidecar) and each frame border of the technique (``renormalise``,
the default; ``leaves``), ``match_render`` fits d starting from the true d (the converted d) with ``score="held"``
(the pixels whose starting kernel the frame holds) and ``score="all"`` (every SSS pixel). Printed: the fitted d over
the true d per channel, and the rel_l2 after the fit on the scored pixels and on all SSS pixels. docs/match.md has
the figures (the Cycles frame with --held-fraction 0.99 --max-steps 8).
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))

from default_candidates import CYCLES, load_blender, load_mitsuba  # noqa: E402  (the defaults' table's frames)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--max-steps", type=int, default=12)
    ap.add_argument("--start", type=float, default=1.0, help="the start d as a multiple of the true d")
    ap.add_argument("--held-fraction", type=float, default=0.95)
    ap.add_argument("--frames", default="skin_closeup,blender")
    ap.add_argument("--borders", default="renormalise,leaves")
    ap.add_argument("--scores", default="held,all")
    ap.add_argument("--json", type=pathlib.Path)
    args = ap.parse_args(argv)

    import jax

    jax.config.update("jax_enable_x64", False)
    import sss_jax as sj
    from sss_jax._match import match_frame, match_render

    loads = {"blender": load_blender, "skin_closeup": lambda: load_mitsuba("skin_closeup"),
             "marble_objects": lambda: load_mitsuba("marble_objects"),
             **{f"cycles_{n}": (lambda n=n: load_blender(CYCLES, n)) for n in ("closeup", "grazing", "far")}}
    rows = []
    for name in args.frames.split(","):
        b, cam, mat, truth, mask = loads[name]()
        ids = np.where(mask, 1, 0).astype(np.int32)
        b = sj.Buffers(irradiance=b.irradiance, depth=b.depth, albedo=b.albedo, normal=b.normal,
                       material_id=jax.numpy.asarray(ids))
        frame = match_frame(b, cam, truth, name=name)
        true_d = np.asarray(mat.d_mm, np.float64).reshape(3)
        start = sj.BurleyMaterial(mat.albedo, (args.start * true_d).astype(np.float32))
        for border in args.borders.split(","):
            for score in args.scores.split(","):
                t0 = time.perf_counter()
                r = match_render(frame, start, technique=sj.Burley(samples=args.samples, border=border,
                                                                   interpolation="bilinear"),
                                 score=score, held_fraction=args.held_fraction, max_steps=args.max_steps)
                d = np.asarray(r.parameters["id1"]["d_mm"], np.float64)
                sc = r.scored["frames"][0]
                row = {"frame": name, "border": border, "score": score, "held_fraction": args.held_fraction,
                       "d_over_true": (d / true_d).tolist(), "d_mm": d.tolist(), "true_d_mm": true_d.tolist(),
                       "scored": [sc["scored_pixels"], sc["sss_pixels"]],
                       "rel_l2_scored_after": r.errors["fitted"]["scored"]["after"]["pooled"]["all"],
                       "rel_l2_all_before": r.errors["fitted"]["before"]["pooled"]["all"],
                       "rel_l2_all_after": r.errors["fitted"]["after"]["pooled"]["all"],
                       "solver": r.solver["result"], "iterations": r.solver["iterations"],
                       "seconds": round(time.perf_counter() - t0, 1)}
                rows.append(row)
                ratio = ", ".join(f"{v:.3f}" for v in d / true_d)
                print(f"{name:13s} border={border:11s} score={score:4s} d/true {ratio}  scored "
                      f"{sc['scored_pixels']}/{sc['sss_pixels']}  rel_l2 scored {row['rel_l2_scored_after']:.4f}"
                      f" all {row['rel_l2_all_before']:.4f} -> {row['rel_l2_all_after']:.4f}  ({r.solver['result']}, "
                      f"{r.solver['iterations']} it, {row['seconds']} s)", flush=True)
    if args.json:
        from sss_jax._io import write_json_atomic

        write_json_atomic(args.json, rows)


if __name__ == "__main__":
    main()
