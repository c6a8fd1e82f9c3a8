"""The issue-17 goal table through the public functions, on whatever backend JAX runs on (meant for an H100/H200).

    python scripts/gpu_goals.py [--size 1920x1080] [--repeats 30] [--impl auto] [--reference-size 640x360] [--json OUT]

Each row: compile seconds (first call minus a timed call) and the median of ``--repeats`` timed calls after it
(``block_until_ready``), demo scene, float32. ``--impl`` picks the formulation (auto, gather, pallas, or a CPU one:
compacted/banded via xla-cpu); run it once per formulation to compare them on the same warm machine.
``--semantics defaults`` (the default, issue #28's table) runs the library's defaults through the public functions,
no option changed (Burley: the rotated spiral, bilinear fetches, the renormalised border; separable: 25 taps, the
renormalised border), which every formulation implements; ``--semantics gpu`` runs Burley's fixed spiral (the rows
of issue #17, taken before the rotated spiral existed). Needs neither OpenCV nor colour-science.
"""

import argparse
import json
import sys
import time

import jax
import jax.numpy as jnp

GOALS_MS = {"separable 25": 0.5, "burley 32": 1.0, "burley 32 jit": 1.0, "translucency": 0.1,
            "grad burley 32 (d)": 5.0, "separable 25 x8 vmap": 4.0, "reference": 50.0}  # reference at 640x360


def main() -> int:
    import sss_jax as sj
    from sss_jax._demo import demo_burley_material
    from sss_jax._timing import time_call

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="1920x1080")
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--impl", default="auto", choices=["auto", "gather", "pallas", "xla-cpu", "xla-gpu"])
    ap.add_argument("--reference-size", default="640x360")
    ap.add_argument("--semantics", default="defaults", choices=["defaults", "gpu"],
                    help="defaults: the library's defaults (issue #28); gpu: Burley's fixed spiral (issue #17)")
    ap.add_argument("--json")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))
    mat = demo_burley_material()
    sta = sj.STAParams(distortion=0.2, power=4.0, scale=(1.0, 0.8, 0.6), ambient=0.05, thickness_mm=(6.0, 3.5, 2.0))
    scene = sj.demo_scene(h, w)
    b, cam = scene.buffers, scene.camera
    rw, rh = (int(v) for v in args.reference_size.lower().split("x"))
    small = sj.demo_scene(rh, rw)
    batch = jax.tree.map(lambda a: jnp.stack([a] * 8), b)
    impl = args.impl
    sep_opts = dict(border="renormalise") if args.semantics == "gpu" else {}
    bur_opts = dict(pattern="fixed", border="renormalise") if args.semantics == "gpu" else {}
    rows = {
        "separable 25": lambda: sj.separable(b, mat, cam, taps=25, impl=impl, **sep_opts),
        "burley 32": lambda: sj.burley(b, mat, cam, samples=32, impl=impl, **bur_opts),
        "burley 32 jit": (lambda f: lambda: f(b))(jax.jit(lambda bb: sj.burley(bb, mat, cam, samples=32, impl=impl,
                                                                                **bur_opts))),
        "translucency": lambda: sj.translucency(b, sta, cam, scene.back_light),
        "grad burley 32 (d)": (lambda g: lambda: g(mat.d_mm))(jax.jit(jax.grad(
            lambda d: jnp.sum(sj.burley(b, sj.BurleyMaterial(mat.albedo, d), cam, samples=32, impl=impl,
                                        **bur_opts))))),
        "separable 25 x8 vmap": (lambda f: lambda: f(batch))(jax.jit(jax.vmap(
            lambda bb: sj.separable(bb, mat, cam, taps=25, impl=impl, **sep_opts)))),
        "reference": lambda: sj.reference(small.buffers, mat, small.camera),
    }
    device = jax.devices()[0]
    out = {"backend": jax.default_backend(), "device": getattr(device, "device_kind", str(device)),
           "jax": jax.__version__, "impl": impl, "semantics": args.semantics, "size": [w, h], "date": time.strftime("%Y-%m-%d"), "rows": {}}
    print(f"{out['device']} ({out['backend']}), jax {out['jax']}, impl {impl}, {w}x{h}, medians of {args.repeats}")
    for name, fn in rows.items():
        _, seconds, compile_s = time_call(fn, args.repeats)
        ms = 1e3 * seconds
        goal = GOALS_MS[name]
        out["rows"][name] = {"ms": round(ms, 3), "compile_s": round(compile_s, 2), "goal_ms": goal}
        print(f"  {name:24s} {ms:10.3f} ms   compile {compile_s:6.2f} s   goal <= {goal} ms "
              f"{'met' if ms <= goal else 'NOT met'}", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
