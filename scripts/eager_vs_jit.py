"""Eager calls against the same calls under ``jax.jit`` (issue #28: "eager calls cost what jitted calls cost").

    python scripts/eager_vs_jit.py [--size 256x144] [--rounds 41]

Each technique's default call on the demo scene (its bench material: the demo's three Burley materials; STA with the
bench's parameters and the scene's back light), eagerly (what a user's script does: the host checks, the dispatch,
the compiled pass) and as the same call under ``jax.jit`` with every argument traced (``jax.jit(lambda buffers,
material, camera: technique(buffers, material, camera))``: the same program, no host work), timed alternately in
one process after a warm-up; prints the medians, their ratio (the goal: eager <= 1.2 x jit) and the load average.
A third column closes over the material and camera instead (XLA then folds them into the program as constants: a
smaller program, not less host work; shown, not the goal's comparison). A ratio below 1 means the eager path does
less than the jitted one (Burley compacts the active pixels on the host, which a traced call cannot).
"""

import argparse
import os
import sys
import time
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))  # the checkout this script is in, not another installed copy


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="256x144", help="frame WxH (default 256x144)")
    ap.add_argument("--rounds", type=int, default=41)
    a = ap.parse_args()
    w, h = (int(v) for v in a.size.split("x"))
    warnings.simplefilter("ignore")
    import jax
    import numpy as np

    import sss_jax as sj
    from sss_jax._demo import demo_burley_material

    scene = sj.demo_scene(h, w)
    b, cam = scene.buffers, scene.camera
    mat = demo_burley_material()
    sta = sj.STAParams(distortion=0.2, power=4.0, scale=(1.0, 0.8, 0.6), ambient=0.05, thickness_mm=(6.0, 3.5, 2.0))
    calls = {  # (the call, its material)
        "translucency": (lambda bb, p, c: sj.translucency(bb, p, c, scene.back_light), sta),
        "separable": (lambda bb, p, c: sj.separable(bb, p, c), mat),
        "burley": (lambda bb, p, c: sj.burley(bb, p, c), mat),
    }
    rows = []
    for name, (call, m) in calls.items():
        traced_all, closed = jax.jit(call), jax.jit(lambda bb, call=call, m=m: call(bb, m, cam))
        fns = {"eager": lambda call=call, m=m: call(b, m, cam),
               "jit": lambda f=traced_all, m=m: f(b, m, cam),
               "jit, closed over": lambda f=closed: f(b)}
        for f in fns.values():
            jax.block_until_ready(f())
            jax.block_until_ready(f())
        times = {k: [] for k in fns}
        for _ in range(a.rounds):
            for label, f in fns.items():
                t0 = time.perf_counter()
                jax.block_until_ready(f())
                times[label].append(time.perf_counter() - t0)
        rows.append((name, *(float(np.median(times[k])) for k in fns)))
    print(f"{w}x{h}, {a.rounds} rounds, load average {os.getloadavg()[0]:.1f}, backend {jax.default_backend()}")
    worst = 0.0
    for name, e, j, c in rows:
        worst = max(worst, e / j)
        print(f"  {name:13s} eager {1e3 * e:8.2f} ms   jit {1e3 * j:8.2f} ms   eager/jit {e / j:5.2f}   "
              f"(closed over: {1e3 * c:8.2f} ms)")
    print(f"worst eager/jit {worst:.2f} (goal <= 1.2: {'met' if worst <= 1.2 else 'not met'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
