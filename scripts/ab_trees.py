"""Time a technique in this checkout against another commit's, both imported in one process and called alternately.

    python scripts/ab_trees.py --base a4efe04 [--technique burley|separable|hdrp|eevee-next|reference]
                               [--size 640x360] [--rounds 16] [--calls 5]

The base commit's ``sss_jax`` (``git archive``) is imported as a package of another name beside this checkout's, so
both run in the same process on the same buffers: rounds of ``--calls`` calls of each, the order swapped every
round, after warm-up calls. Prints each tree's median and lower-quartile time, their ratio (base / this, below 1:
the base is faster) and the largest difference between the two outputs (0 where the change should not move a
pixel). This is the reading docs/performance.md trusts: ``../shared/tools/perf_ab.py`` (one process per tree and
round) swings by +-20-40% on a shared 2-core machine.
"""

import argparse
import io
import os
import subprocess
import sys
import tarfile
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)  # this checkout's sss_jax, not another installed copy


def import_base(rev: str, where: str):
    """The package ``sss_jax`` of commit ``rev``, unpacked under ``where`` as ``sss_jax_base`` and imported."""
    archive = subprocess.run(["git", "-C", ROOT, "archive", rev, "sss_jax"], check=True, capture_output=True).stdout
    with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
        # the "data" filter where this Python has it (3.10.12+, 3.11.4+): a commit's own files, nothing outside
        tar.extractall(where, **({"filter": "data"} if hasattr(tarfile, "data_filter") else {}))
    os.rename(os.path.join(where, "sss_jax"), os.path.join(where, "sss_jax_base"))
    sys.path.insert(0, where)
    import sss_jax_base

    return sss_jax_base


# each technique's call (its defaults, and the counts the bench times; eevee-next 4 TAA frames of its 16, the
# reference an 8-px window: calls of ~0.1-0.5 s at 640x360)
COUNTS = {"burley": {"samples": 32}, "separable": {"taps": 25}, "hdrp": {}, "eevee-next": {"frames": 4},
          "reference": {"radius_px": 8}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, help="the commit to compare with (any git revision)")
    ap.add_argument("--technique", default="burley", choices=tuple(COUNTS))
    ap.add_argument("--size", default="640x360", help="WxH of the demo frame (default 640x360)")
    ap.add_argument("--rounds", type=int, default=16)
    ap.add_argument("--calls", type=int, default=5, help="calls of each tree per round")
    args = ap.parse_args()

    import numpy as np

    import sss_jax as this
    from sss_jax._demo import demo_burley_material

    w, h = (int(v) for v in args.size.lower().split("x"))
    with tempfile.TemporaryDirectory() as where:
        base = import_base(args.base, where)
        scene = this.demo_scene(h, w)
        b, cam = scene.buffers, scene.camera
        mat = demo_burley_material()
        count = COUNTS[args.technique]
        b_base = base.Buffers(irradiance=b.irradiance, depth=b.depth, albedo=b.albedo, material_id=b.material_id)
        mat_base = base.BurleyMaterial(np.asarray(mat.albedo), np.asarray(mat.d_mm))
        cam_base = base.Camera(cam.focal_px, cam.mm_per_unit)
        name = args.technique.replace("-", "_")  # the package's function of the technique (sss_jax.eevee_next, ...)
        f_this, f_base = getattr(this, name), getattr(base, name)
        runs = {"this": lambda: f_this(b, mat, cam, **count), "base": lambda: f_base(b_base, mat_base, cam_base, **count)}
        out = {name: np.asarray(fn(), np.float64) for name, fn in runs.items()}
        for _ in range(5):
            for fn in runs.values():
                fn().block_until_ready()
        times = {name: [] for name in runs}
        for r in range(args.rounds):
            for name in (("this", "base") if r % 2 == 0 else ("base", "this")):
                for _ in range(args.calls):
                    t0 = time.perf_counter()
                    runs[name]().block_until_ready()
                    times[name].append(time.perf_counter() - t0)
    med = {k: float(np.median(v)) for k, v in times.items()}
    q25 = {k: float(np.percentile(v, 25)) for k, v in times.items()}
    diff = float(np.nanmax(np.abs(out["this"] - out["base"])) / max(np.nanmax(np.abs(out["base"])), 1e-30))
    print(f"{args.technique} at {w}x{h}, {args.rounds} rounds of {args.calls} calls each, load average "
          f"{', '.join(f'{v:.2f}' for v in os.getloadavg())}")
    for name in ("base", "this"):
        print(f"  {name:4s} ({args.base if name == 'base' else 'checkout'}): median {1e3 * med[name]:.2f} ms, "
              f"lower quartile {1e3 * q25[name]:.2f} ms")
    print(f"  base / this: {med['base'] / med['this']:.3f} (lower quartiles {q25['base'] / q25['this']:.3f}); "
          f"largest output difference {diff:.2e} of the base's largest value")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
