"""Batch benchmarks: throughput, a long run with corrupt frames (memory flat, nothing lost), resume, a huge frame.

    python scripts/bench_batch.py [--frames 64] [--size 512] [--technique burley] [--devices N]
    python scripts/bench_batch.py --long [--frames 1000] [--size 256] [--corrupt 0.1]
    python scripts/bench_batch.py --large 8000
    python scripts/bench_batch.py --vs-pass [--frames 200] [--size 256] [--technique burley] [--samples 32]

Default: frames are generated from the demo scene with a varying key light and written to a temporary directory
first (not timed); then process_frames runs over them, compile included in the wall time and reported separately.

``--long``: 1,000 frames of 256x256, 10% of them corrupt (empty, truncated, garbage, no depth channel: cycled), on
the CPU. Checks that every good frame is written and complete and every bad one is named as failed in the manifest,
reports frames/s and the resident memory (RSS) after frame 100 and after the last frame (the growth between them is
what a leak would show), then runs the batch again with resume and checks every frame is skipped with the outputs
byte-identical. Exit status 0 only when all of that holds.

``--vs-pass``: the batch against its pass, on the same frames in one run: the pass alone (the technique called on
each frame's buffers, already in memory: no reading, no writing) and then ``process_frames`` over the files
(reading, checks, writing, manifest included), each after one warm-up frame so compilation counts in neither, and
the pass alone again after the batch; prints both frames/s and their ratio against the faster pass run (the goal:
batch >= 0.75 x pass), and the machine's load; and, for what the files and the book-keeping cost, the pass with
``COMPUTE_THREADS`` frames at a time (as the batch computes small frames) and the batch's share of that; and the
ceiling of the ratio on this machine: the CPU time a frame of the pass (as it runs alone), of reading a frame and of
writing its output (each measured alone, one thread), packed perfectly onto the cores with the book-keeping free.

``--large N``: one NxN frame (written by a child process, so its generation does not count), processed in tiles;
reports the wall time and the peak resident memory of the processing process, and checks the result is complete.
"""

import argparse
import hashlib
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)  # the checkout this script is in, not another installed copy


def _count(args) -> dict:
    """The technique's own count (a batch warns of one its technique does not have)."""
    return {"samples": args.samples} if args.technique == "burley" else {"taps": args.taps}


def rss_mib() -> float:
    """Current resident set size (not the peak), from /proc/self/statm."""
    with open("/proc/self/statm") as f:
        pages = int(f.read().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def make_frames(src: str, frames: int, size: int, corrupt: float) -> list[int]:
    """Write the frames; return the indices of the corrupt ones (every round(1/corrupt)-th frame)."""
    import numpy as np

    import sss_jax as sj
    from sss_jax import _io

    scene = sj.demo_scene(size, size)
    b = scene.buffers
    irr = np.asarray(b.irradiance)
    attrs = {"sss_jax:focal_px": float(scene.camera.focal_px), "sss_jax:mm_per_unit": 10.0}
    step = round(1 / corrupt) if corrupt > 0 else 0
    bad = [i for i in range(frames) if step and i % step == step // 2]
    kinds = ["empty", "truncated", "garbage", "no_depth"]
    for i in range(frames):
        path = os.path.join(src, f"frame{i:04d}.exr")
        gain = 0.6 + 0.8 * (i / max(frames - 1, 1))
        ch = {"R": irr[..., 0] * gain, "G": irr[..., 1] * gain, "B": irr[..., 2], "Z": np.asarray(b.depth),
              "id": np.asarray(b.material_id).astype(np.float32)}
        if i in bad:
            kind = kinds[bad.index(i) % len(kinds)]
            if kind == "empty":
                open(path, "wb").close()
                continue
            if kind == "garbage":
                with open(path, "wb") as f:
                    f.write(b"\x76\x2f\x31\x01" + os.urandom(4096))
                continue
            if kind == "no_depth":
                ch.pop("Z")
            _io.write_exr(path, ch, attributes=attrs)
            if kind == "truncated":
                with open(path, "rb") as f:
                    data = f.read()
                with open(path, "wb") as f:
                    f.write(data[: len(data) // 2])
            continue
        _io.write_exr(path, ch, attributes=attrs)
    return bad


def make_large(path: str, n: int, focal_px: float) -> None:
    """An NxN frame: a lit sphere (SSS, id 1: the demo's skin, d up to 3 mm) in front of a wall (id 0), planar depth
    in scene units (cm, 60-100 cm away); d at the front is ``3 focal_px / 600`` px."""
    import numpy as np

    from sss_jax import _io

    y, x = np.ogrid[:n, :n]
    u = ((x + 0.5) / n - 0.5).astype(np.float32)
    v = ((y + 0.5) / n - 0.5).astype(np.float32)
    rr = u * u + v * v
    inside = rr < 0.16
    cap = np.sqrt(np.maximum(0.16 - rr, 0.0)).astype(np.float32)
    depth = np.where(inside, 100.0 - 100.0 * cap, 150.0).astype(np.float32)
    shade = np.where(inside, 0.2 + 0.8 * np.clip(cap / 0.4 + u, 0.0, 1.0), 0.5).astype(np.float32)
    del cap, rr
    ch = {"R": shade, "G": shade * 0.8, "B": shade * 0.6, "Z": depth, "id": inside.astype(np.float32)}
    _io.write_exr(path, ch, attributes={"sss_jax:focal_px": float(focal_px), "sss_jax:mm_per_unit": 10.0})


def digests(folder: str) -> dict[str, str]:
    return {n: hashlib.sha256(open(os.path.join(folder, n), "rb").read()).hexdigest()
            for n in sorted(os.listdir(folder)) if n.endswith(".exr")}


def long_run(args) -> int:
    from sss_jax._batch import MANIFEST_NAME, process_frames
    from sss_jax._demo import demo_burley_material
    from sss_jax._io import exr_is_complete

    mat = demo_burley_material()
    with tempfile.TemporaryDirectory() as tmp:
        src, out = os.path.join(tmp, "src"), os.path.join(tmp, "out")
        os.mkdir(src)
        # the frames are written by a child process: their generation does not count in this process's memory
        code = (f"import sys; sys.path.insert(0, {HERE!r}); import bench_batch as b; "
                f"print(b.make_frames({src!r}, {args.frames}, {args.size}, {args.corrupt}))")
        bad = json.loads(subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True,
                                        env=dict(os.environ, PYTHONPATH=ROOT)).stdout.strip().splitlines()[-1])
        marks = {}
        count = [0]
        settled = min(100, args.frames)  # the memory after the first frames settle, against the last frame's

        def on_done(r):
            count[0] += 1
            if count[0] in (1, settled, args.frames):
                marks[count[0]] = rss_mib()

        t0 = time.perf_counter()
        r = process_frames(os.path.join(src, "*.exr"), args.technique, mat, out_dir=out, progress=False,
                           on_frame_done=on_done)
        wall = time.perf_counter() - t0
        with open(os.path.join(out, MANIFEST_NAME)) as f:
            book = json.load(f)
        failed = {os.path.basename(f["input"]) for f in book["frames"] if f["status"] == "failed"}
        done = {os.path.basename(f["output"]) for f in book["frames"] if f["status"] == "done"}
        expect_bad = {f"frame{i:04d}.exr" for i in bad}
        expect_good = {f"frame{i:04d}.exr" for i in range(args.frames)} - expect_bad
        on_disk = {n for n in os.listdir(out) if n != MANIFEST_NAME}
        complete = all(exr_is_complete(os.path.join(out, n)) for n in on_disk)
        before = digests(out)
        t1 = time.perf_counter()
        again = process_frames(os.path.join(src, "*.exr"), args.technique, mat, out_dir=out, progress=False)
        wall_resume = time.perf_counter() - t1
        skipped = sum(f.status == "skipped" for f in again.frames)
        identical = digests(out) == before
    ok = len(r.frames) - len(r.failed)
    good = (failed == expect_bad and done == expect_good == on_disk and complete and book["state"] == "complete"
            and skipped == len(expect_good) and identical)
    print(f"long run: {args.frames} frames of {args.size}x{args.size}, {len(bad)} corrupt, {args.technique}, CPU")
    print(f"  frames written {ok} (expected {len(expect_good)}), failed {len(r.failed)} (all named in the manifest: "
          f"{failed == expect_bad}), every written frame complete: {complete}, manifest equals the disk: "
          f"{done == on_disk}")
    print(f"  throughput: {args.frames / wall:.2f} frames/s ({wall:.1f} s, read + compute + write + manifest; "
          f"{ok / wall:.2f} good frames/s)")
    print(f"  resident memory: {marks.get(1, 0):.0f} MiB after frame 1, {marks.get(settled, 0):.0f} MiB after frame "
          f"{settled}, {marks.get(args.frames, 0):.0f} MiB after frame {args.frames}: growth {settled} -> "
          f"{args.frames} {marks.get(args.frames, 0) - marks.get(settled, 0):+.0f} MiB; peak {peak_mib():.0f} MiB")
    print(f"  resume: {skipped} of {len(again.frames) - len(again.failed)} good frames skipped, outputs "
          f"byte-identical: {identical}, {wall_resume:.1f} s ({wall / max(wall_resume, 1e-9):.0f}x faster)")
    print("  all checks hold" if good else "  CHECK FAILED")
    return 0 if good else 1


def large_run(args) -> int:
    from sss_jax._batch import process_frames
    from sss_jax._demo import demo_burley_material
    from sss_jax._io import exr_is_complete

    n = args.large
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, f"large{n}.exr")
        focal = args.focal_px or n / 8
        code = (f"import sys; sys.path.insert(0, {HERE!r}); import bench_batch as b; "
                f"b.make_large({path!r}, {n}, {focal})")
        subprocess.run([sys.executable, "-c", code], check=True, env=dict(os.environ, PYTHONPATH=ROOT))
        size_mib = os.path.getsize(path) / 2**20
        base = rss_mib()
        t0 = time.perf_counter()
        r = process_frames(path, args.technique, demo_burley_material(), out_dir=os.path.join(tmp, "out"),
                           progress=True, **_count(args))
        wall = time.perf_counter() - t0
        out = os.path.join(tmp, "out", f"large{n}.exr")
        complete = r.ok and exr_is_complete(out)
    buffers_mib = n * n * 5 * 4 / 2**20  # R, G, B, Z, id as float32
    print(f"large frame: {n}x{n}, {args.technique} ({args.samples} samples / {args.taps} taps), focal {focal:g} px "
          f"(d = {3 * focal / 600:.1f} px at the front), EXR {size_mib:.0f} MiB on disk, {buffers_mib:.0f} MiB of "
          f"float32 buffers")
    print(f"  processed: {r.frames[0].status} {r.frames[0].message} complete: {complete}, {wall:.1f} s")
    print(f"  peak resident memory {peak_mib():.0f} MiB ({peak_mib() / buffers_mib:.1f}x the input buffers; "
          f"{base:.0f} MiB before the frame: the JAX runtime)")
    return 0 if complete else 1


def vs_pass(args) -> int:
    from concurrent.futures import ThreadPoolExecutor

    import numpy as np

    import sss_jax as sj
    from sss_jax import _io
    from sss_jax._batch import COMPUTE_THREADS, process_frames
    from sss_jax._demo import demo_burley_material
    from sss_jax._machine import usable_cores

    mat = demo_burley_material()
    fn = {"burley": lambda b, c: sj.burley(b, mat, c, samples=args.samples),
          "separable": lambda b, c: sj.separable(b, mat, c, taps=args.taps)}[args.technique]
    with tempfile.TemporaryDirectory() as tmp:
        src = os.path.join(tmp, "src")
        os.mkdir(src)
        make_frames(src, args.frames, args.size, 0.0)
        paths = sorted(os.path.join(src, n) for n in os.listdir(src))
        frames = [_io.read_frame(p) for p in paths]
        inputs = [(f.to_buffers(), sj.Camera(f.focal_px, 10.0)) for f in frames]
        cpu = {}  # CPU seconds (every thread of the process) of the last run of each

        def pass_alone() -> float:
            t0, c0 = time.perf_counter(), time.process_time()
            for b, c in inputs:
                np.asarray(fn(b, c))
            cpu["pass"] = time.process_time() - c0
            return time.perf_counter() - t0

        def pass_overlapped() -> float:
            # the pass as the batch computes small frames: COMPUTE_THREADS calls at once (no files): what the
            # batch's compute alone can reach on this machine
            with ThreadPoolExecutor(COMPUTE_THREADS) as pool:
                t0 = time.perf_counter()
                list(pool.map(lambda bc: np.asarray(fn(*bc)), inputs))
                return time.perf_counter() - t0

        np.asarray(fn(*inputs[0]))  # compile
        pass_s = [pass_alone()]
        overlapped_s = pass_overlapped()
        process_frames(paths[:1], args.technique, mat, out_dir=os.path.join(tmp, "warm"), progress=False,
                       **_count(args), devices=None)
        t0, c0 = time.perf_counter(), time.process_time()
        r = process_frames(paths, args.technique, mat, out_dir=os.path.join(tmp, "out"), progress=False,
                           **_count(args))
        batch_s, cpu["batch"] = time.perf_counter() - t0, time.process_time() - c0
        # the pass again after the batch: the ratio takes the faster of the two (load that comes or goes during
        # the run never flatters the batch)
        pass_s.append(pass_alone())
        # the files alone, one thread, nothing beside them: a frame read as the batch reads it (decoded, checked,
        # buffers) and an output written as the batch writes it (ZIP float, atomic); CPU seconds a frame
        some = paths[: min(20, len(paths))]
        image = np.asarray(fn(*inputs[0]))
        c0 = time.process_time()
        for p in some:
            _io.read_frame(p).to_buffers()
        cpu["read"] = (time.process_time() - c0) / len(some)
        c0 = time.process_time()
        for k in range(len(some)):
            _io.write_exr(os.path.join(tmp, f"alone{k}.exr"), image, attributes={"sss_jax:technique": args.technique})
        cpu["write"] = (time.process_time() - c0) / len(some)
    ok = sum(f.status == "done" for f in r.frames)
    pass_fps, batch_fps = args.frames / min(pass_s), ok / batch_s
    count = f"{args.samples} samples" if args.technique == "burley" else f"{args.taps} taps"
    print(f"{args.frames} frames of {args.size}x{args.size}, {args.technique} {count}, load average "
          f"{', '.join(f'{v:.2f}' for v in os.getloadavg())}")
    print(f"  pass alone: {pass_fps:.2f} frames/s (the faster of {pass_s[0]:.2f} s before and {pass_s[1]:.2f} s "
          "after the batch; the technique on buffers in memory)")
    print(f"  batch:      {batch_fps:.2f} frames/s ({batch_s:.1f} s; read + checks + compute + write + manifest)")
    print(f"  batch / pass: {batch_fps / pass_fps:.3f} (goal >= 0.75)")
    print(f"  (the pass {COMPUTE_THREADS} frames at a time, as the batch computes small frames, no files: "
          f"{args.frames / overlapped_s:.2f} frames/s; the batch reaches {batch_fps * overlapped_s / args.frames:.3f} "
          "of it)")
    # what bounds the ratio on a small machine: the batch's CPU time a frame (reading, checking, writing on top of
    # the pass's) against the cores there are; the batch cannot run faster than its CPU time over the cores
    if ok:  # (no frame done: nothing to divide by, and the exit status says so)
        batch_cpu, cores = cpu["batch"] / ok, usable_cores()
        print(f"  CPU time a frame: pass {1e3 * cpu['pass'] / args.frames:.1f} ms, batch {1e3 * batch_cpu:.1f} ms "
              f"({cores} cores: the batch's floor is {1e3 * batch_cpu / cores:.1f} ms a frame, "
              f"{cores / batch_cpu:.0f} frames/s)")
        # the ceiling of the ratio on this machine: the pass's CPU (as it runs alone, XLA's threads and all) and
        # the files' CPU measured alone, packed perfectly onto the cores, book-keeping and hand-offs free
        least = cpu["pass"] / args.frames + cpu["read"] + cpu["write"]
        print(f"  files alone (one thread, CPU a frame): read {1e3 * cpu['read']:.1f} ms, write "
              f"{1e3 * cpu['write']:.1f} ms; with the pass's {1e3 * cpu['pass'] / args.frames:.1f} ms that is "
              f"{1e3 * least:.1f} ms a frame: packed perfectly on {cores} cores, book-keeping free, at most "
              f"{cores / least:.0f} frames/s, {cores / least / pass_fps:.2f} of the pass alone")
    return 0 if ok == args.frames else 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--size", type=int, default=None)
    ap.add_argument("--technique", default="burley", choices=("burley", "separable"))
    ap.add_argument("--devices", type=int, default=1, help="split the host CPU into N jax devices")
    ap.add_argument("--long", action="store_true", help="the long run: 1,000 frames of 256x256, 10%% corrupt")
    ap.add_argument("--corrupt", type=float, default=0.1, help="fraction of corrupt frames in --long")
    ap.add_argument("--large", type=int, help="one NxN frame in tiles: peak memory")
    ap.add_argument("--vs-pass", action="store_true", help="batch frames/s against the pass alone, one run")
    ap.add_argument("--focal-px", type=float, help="--large: focal length in px (default N/8)")
    ap.add_argument("--samples", type=int, default=32, help="burley samples (default 32)")
    ap.add_argument("--taps", type=int, default=25, help="separable taps (default 25)")
    args = ap.parse_args()
    if args.devices > 1:
        os.environ["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={args.devices}"
    if args.long:
        args.frames = args.frames or 1000
        args.size = args.size or 256
        return long_run(args)
    if args.large:
        return large_run(args)
    if args.vs_pass:
        args.frames = args.frames or 200
        args.size = args.size or 256
        return vs_pass(args)
    args.frames = args.frames or 64
    args.size = args.size or 512
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
    ok = sum(f.status == "done" for f in r.frames)
    print(f"technique {args.technique}, {args.frames} frames of {args.size}x{args.size}, {args.devices} device(s)")
    print(f"first frame (compile + run): {first:.2f} s")
    print(f"throughput: {ok / wall:.2f} frames/s ({wall:.1f} s for {ok} frames, read + compute + write)")
    print(f"peak resident memory: {peak_mib():.0f} MiB (one input frame: {input_bytes / 2**20:.1f} MiB)")
    return 0 if ok == args.frames else 1


if __name__ == "__main__":
    sys.exit(main())
