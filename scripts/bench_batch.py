"""Batch throughput: frames/s for a 64-frame 512x512 sequence on this machine, and peak memory.

    python scripts/bench_batch.py [--frames 64] [--size 512] [--technique burley] [--devices N]

Frames are generated from the demo scene with a varying key light and written to a temporary directory first (not
timed); then process_frames runs over them, compile included in the wall time and reported separately.
"""

import argparse
import os
import resource
import sys
import tempfile
import time


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=64)
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--technique", default="burley", choices=("burley", "separable"))
    ap.add_argument("--devices", type=int, default=1, help="split the host CPU into N jax devices")
    args = ap.parse_args()
    if args.devices > 1:
        os.environ["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={args.devices}"
    import numpy as np

    import sss_jax as sj
    from sss_jax import _io
    from sss_jax._batch import process_frames
    from sss_jax._demo import demo_burley_material

    scene = sj.demo_scene(args.size, args.size)
    b = scene.buffers
    irr = np.asarray(b.irradiance)
    with tempfile.TemporaryDirectory() as tmp:
        src = os.path.join(tmp, "src")
        os.mkdir(src)
        input_bytes = 0
        for i in range(args.frames):
            gain = 0.6 + 0.8 * (i / max(args.frames - 1, 1))
            ch = {"R": irr[..., 0] * gain, "G": irr[..., 1] * gain, "B": irr[..., 2], "Z": np.asarray(b.depth),
                  "id": np.asarray(b.material_id).astype(np.float32)}
            _io.write_exr(os.path.join(src, f"frame{i:04d}.exr"), ch,
                          attributes={"sss_jax:focal_px": float(scene.camera.focal_px), "sss_jax:mm_per_unit": 10.0})
            input_bytes = sum(v.nbytes for v in ch.values())
        mat = demo_burley_material()
        # one frame first: the compile, measured apart from the throughput
        t0 = time.perf_counter()
        process_frames([os.path.join(src, "frame0000.exr")], args.technique, mat, out_dir=os.path.join(tmp, "warm"),
                       progress=False)
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        r = process_frames(os.path.join(src, "*.exr"), args.technique, mat, out_dir=os.path.join(tmp, "out"),
                           progress=False)
        wall = time.perf_counter() - t0
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    ok = sum(f.status == "ok" for f in r.frames)
    print(f"technique {args.technique}, {args.frames} frames of {args.size}x{args.size}, {args.devices} device(s)")
    print(f"first frame (compile + run): {first:.2f} s")
    print(f"throughput: {ok / wall:.2f} frames/s ({wall:.1f} s for {ok} frames, read + compute + write)")
    print(f"peak resident memory: {peak_mib:.0f} MiB (one input frame: {input_bytes / 2**20:.1f} MiB)")
    return 0 if ok == args.frames else 1


if __name__ == "__main__":
    sys.exit(main())
