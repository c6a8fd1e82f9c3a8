"""Batch processing: sharding over devices, resuming after an interruption, per-frame failures, process shares."""

import json
import math
import os
import pathlib
import re
import signal
import sys
import types

import jax
import numpy as np
import pytest

import sss_jax as sj
from sss_jax import _io
from sss_jax._batch import MANIFEST_NAME, frame_seed, frames_for_process, process_frames

MAT = sj.BurleyMaterial([[0.8, 0.6, 0.5]] * 3, [[3.0, 1.4, 0.8], [2.2, 1.9, 1.6], [3.5, 2.4, 1.4]])


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    d = tmp_path_factory.mktemp("frames")
    scene = sj.demo_scene(40, 48)
    b = scene.buffers
    for i in range(5):
        ch = {"R": np.asarray(b.irradiance[..., 0]) * (1 + 0.2 * i), "G": np.asarray(b.irradiance[..., 1]),
              "B": np.asarray(b.irradiance[..., 2]), "Z": np.asarray(b.depth),
              "id": np.asarray(b.material_id).astype(np.float32)}
        _io.write_exr(d / f"f{i}.exr", ch, attributes={"sss_jax:focal_px": float(scene.camera.focal_px),
                                                      "sss_jax:mm_per_unit": 10.0})
    return d


def read_rgb(path):
    return _io.read_frame(path, channel_map={"irradiance": ["R", "G", "B"], "depth": "R"}).irradiance


@pytest.fixture(scope="module")
def one_device_run(frames, tmp_path_factory):
    """Every frame through burley on one device, uninterrupted: the reference of the sharded run and of the resumed
    one (each ``process_frames`` call compiles its own program, so one run less is one compilation less)."""
    out = tmp_path_factory.mktemp("one_device")
    result = process_frames(str(frames / "*.exr"), "burley", MAT, out_dir=out, samples=8, progress=False,
                            devices=jax.devices()[:1])
    return result, out


def test_four_devices_give_the_pixels_of_one(frames, one_device_run, tmp_path):
    assert len(jax.devices()) == 4  # tests/conftest.py splits the host into 4 CPU devices
    r4 = process_frames(str(frames / "*.exr"), "burley", MAT, out_dir=tmp_path / "o4", samples=8, progress=False)
    r1, o1 = one_device_run
    assert r4.ok and r1.ok and len(r4.frames) == 5
    assert r4.compilations == 1  # one frame shape, one compilation, 5 frames in 2 sharded groups
    # one device runs each frame as a single call does (compacted on the host), four run it vmapped (every pixel
    # computed): the two formulations agree to rounding
    for i in range(5):
        np.testing.assert_allclose(read_rgb(tmp_path / "o4" / f"f{i}.exr"), read_rgb(o1 / f"f{i}.exr"), rtol=1e-6,
                                   atol=1e-6)
    # and each frame equals the single-frame API with that frame's seed (the frame number mixed into the seed)
    f = _io.read_frame(frames / "f3.exr")
    single = np.asarray(sj.burley(f.to_buffers(), MAT, sj.Camera(f.focal_px, 10.0), samples=8,
                                  seed=frame_seed(0, 3)))
    np.testing.assert_allclose(read_rgb(tmp_path / "o4" / "f3.exr"), single, rtol=1e-6, atol=1e-6)


def test_interrupted_batch_resumes_with_identical_output(frames, one_device_run, tmp_path):
    # the same technique and device as the uninterrupted one-device run, whose frames are the reference
    full, ref = one_device_run
    assert full.ok
    done = []

    def stop_after_two(result):
        done.append(result)
        if len(done) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        process_frames(str(frames / "*.exr"), "burley", MAT, out_dir=tmp_path / "run", samples=8, progress=False,
                       devices=jax.devices()[:1], on_frame_done=stop_after_two)
    names = sorted(p.name for p in (tmp_path / "run").iterdir())
    assert names == ["f0.exr", "f1.exr", MANIFEST_NAME]  # complete frames only: no temp or partial files
    book = json.loads((tmp_path / "run" / MANIFEST_NAME).read_text())
    assert book["state"] == "interrupted"
    assert [f["status"] for f in book["frames"]] == ["done", "done", "pending", "pending", "pending"]
    again = process_frames(str(frames / "*.exr"), "burley", MAT, out_dir=tmp_path / "run", samples=8, progress=False,
                           devices=jax.devices()[:1])
    assert [f.status for f in again.frames] == ["skipped", "skipped", "done", "done", "done"]
    for i in range(5):
        np.testing.assert_array_equal(read_rgb(tmp_path / "run" / f"f{i}.exr"), read_rgb(ref / f"f{i}.exr"))
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == [f"f{i}.exr" for i in range(5)] + [MANIFEST_NAME]


def test_a_bad_frame_is_reported_and_the_others_complete(frames, tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    for i in range(3):
        (src / f"f{i}.exr").write_bytes((frames / f"f{i}.exr").read_bytes())
    (src / "f1.exr").write_bytes(b"\x76\x2f\x31\x01 truncated")
    r = process_frames(str(src / "*.exr"), "burley", MAT, out_dir=tmp_path / "o", samples=4, progress=False)
    assert sorted(f.status for f in r.frames) == ["done", "done", "failed"]
    bad = r.failed[0]
    assert bad.input.endswith("f1.exr") and "f1.exr" in bad.message
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["f0.exr", "f2.exr", MANIFEST_NAME]


def test_process_shares_are_disjoint_complete_and_balanced():
    frames = [f"frame{i:04d}.exr" for i in range(103)]
    for count in (1, 2, 3, 8):
        shares = [frames_for_process(frames, i, count) for i in range(count)]
        flat = [f for s in shares for f in s]
        assert sorted(flat) == frames and len(set(flat)) == len(frames)
        sizes = [len(s) for s in shares]
        assert max(sizes) - min(sizes) <= 1
        assert shares == [frames_for_process(frames, i, count) for i in range(count)]  # deterministic
    with pytest.raises(ValueError, match="process_index 3 must be in"):
        frames_for_process(frames, 3, 3)


def test_batch_rejects_bad_arguments(frames, tmp_path):
    with pytest.raises(ValueError, match="unknown technique 'blur'"):
        process_frames(str(frames / "*.exr"), "blur", MAT, out_dir=tmp_path)
    with pytest.raises(ValueError, match="needs radius_px"):
        process_frames(str(frames / "*.exr"), "reference", MAT, out_dir=tmp_path)
    with pytest.raises(_io.SSSInputError, match="no files match"):
        process_frames(str(tmp_path / "none*.exr"), "burley", MAT, out_dir=tmp_path)


PRESET = {"name": "test_skin", "albedo": [0.8, 0.6, 0.5], "burley": {"d_mm": [3.0, 1.4, 0.8]},
          "separable": {"two_gaussian": {"w": [0.5, 0.6, 0.7], "sigma_near_mm": [1.0, 0.6, 0.4],
                                         "sigma_far_mm": [5.0, 3.0, 2.0]}},
          "sta": {"distortion": 0.2, "power": 4.0, "scale": [1, 1, 1], "ambient": [0, 0, 0], "thickness_mm": [2, 2, 2]}}


def test_presets_by_file_and_by_name(frames, tmp_path, monkeypatch):
    import json

    from sss_jax._presets import load_preset

    pdir = tmp_path / "presets"
    pdir.mkdir()
    (pdir / "test_skin.json").write_text(json.dumps(PRESET))
    monkeypatch.setenv("SSS_JAX_PRESETS", str(pdir))
    p = load_preset("test_skin")
    np.testing.assert_allclose(np.asarray(p.two_gaussian.sigma_far_mm)[0], [5.0, 3.0, 2.0])
    by_name = process_frames(str(frames / "f0.exr"), "separable", "test_skin", out_dir=tmp_path / "a", taps=5,
                             progress=False)
    by_file = process_frames(str(frames / "f0.exr"), "separable", str(pdir / "test_skin.json"), out_dir=tmp_path / "b",
                             taps=5, progress=False)
    assert by_name.ok and by_file.ok
    # the preset's two-Gaussian kernel, as the single-frame API computes it
    f = _io.read_frame(frames / "f0.exr")
    direct = np.asarray(sj.separable(f.to_buffers(), p.two_gaussian, sj.Camera(f.focal_px, 10.0), taps=5))
    np.testing.assert_allclose(read_rgb(tmp_path / "a" / "f0.exr"), direct, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(read_rgb(tmp_path / "a" / "f0.exr"), read_rgb(tmp_path / "b" / "f0.exr"))


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d.pop("burley"), "preset is missing burley.d_mm"),
    (lambda d: d.update(albedo=[0.5, 0.5]), "albedo must be a list of 3 numbers"),
    (lambda d: d["burley"].update(d_mm=[-1, 1, 1]), r"invalid preset: d_mm must be finite and >= 0"),
    (lambda d: d["separable"]["two_gaussian"].update(w=[2, 0, 0]), r"invalid preset: w must be >= 0 and <= 1"),
])
def test_invalid_presets_are_named(tmp_path, capsys, mutate, message):
    import copy
    import json

    from sss_jax.cli import main

    data = copy.deepcopy(PRESET)
    mutate(data)
    preset = tmp_path / "bad.json"
    preset.write_text(json.dumps(data))
    src = tmp_path / "in.exr"
    _io.write_exr(src, {"R": np.ones((4, 4)), "G": np.ones((4, 4)), "B": np.ones((4, 4)), "Z": np.ones((4, 4))})
    out = tmp_path / "out.exr"
    assert main(["apply", str(src), "-o", str(out), "--technique", "burley", "--preset", str(preset),
                 "--focal-px", "10"]) == 2
    err = capsys.readouterr().err
    assert "bad.json" in err and re.search(message, err)
    assert not out.exists()
    (tmp_path / "broken.json").write_text("{not json")
    assert main(["apply", str(src), "-o", str(out), "--technique", "burley", "--preset",
                 str(tmp_path / "broken.json"), "--focal-px", "10"]) == 2
    assert "not valid JSON" in capsys.readouterr().err
    assert main(["apply", str(src), "-o", str(out), "--technique", "burley", "--preset", "no_such_preset",
                 "--focal-px", "10"]) == 2
    assert "unknown preset 'no_such_preset'" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------------------------
# outputs never collide, never overwrite an input, and a re-run computes only what changed
# ------------------------------------------------------------------------------------------------------------------


def copy_frame(frames, name, dst):
    dst.parent.mkdir(parents=True, exist_ok=True)
    dst.write_bytes((frames / name).read_bytes())
    return dst


def test_one_name_in_two_folders_gives_two_outputs(frames, tmp_path):
    # a render farm's layout: shots/<shot>/beauty.exr; before, both went to out/beauty.exr, the second over the first
    a = copy_frame(frames, "f0.exr", tmp_path / "shots" / "a" / "beauty.exr")
    b = copy_frame(frames, "f4.exr", tmp_path / "shots" / "b" / "beauty.exr")
    r = process_frames(str(tmp_path / "shots" / "*" / "beauty.exr"), "burley", MAT, out_dir=tmp_path / "out",
                       samples=4, progress=False, devices=jax.devices()[:1])
    assert r.ok and [f.status for f in r.frames] == ["done", "done"]
    for k, (src, out) in enumerate(((a, tmp_path / "out" / "a" / "beauty.exr"),
                                    (b, tmp_path / "out" / "b" / "beauty.exr"))):
        f = _io.read_frame(src)
        # independent of the batch: the single-frame API on that input (no digits in the name: the frame number is
        # its place in the batch)
        single = np.asarray(sj.burley(f.to_buffers(), MAT, sj.Camera(f.focal_px, 10.0), samples=4,
                                      seed=frame_seed(0, k)))
        np.testing.assert_allclose(read_rgb(out), single, rtol=1e-6, atol=1e-6)
    assert not np.array_equal(read_rgb(tmp_path / "out" / "a" / "beauty.exr"),
                              read_rgb(tmp_path / "out" / "b" / "beauty.exr"))


def test_colliding_outputs_are_refused_before_any_write(frames, tmp_path, capsys):
    from sss_jax.cli import main

    # one stem, two extensions: both would be out/f.exr
    a = copy_frame(frames, "f0.exr", tmp_path / "in" / "f.exr")
    b = copy_frame(frames, "f1.exr", tmp_path / "in" / "f.EXR")
    out = tmp_path / "out"
    with pytest.raises(_io.SSSInputError, match=r"f\.exr would be written by .*f\.exr and .*f\.EXR"):
        process_frames([a, b], "burley", MAT, out_dir=out, samples=4, progress=False)
    assert not out.exists() or list(out.rglob("*")) == []
    # explicit outputs: two frames, one file
    with pytest.raises(_io.SSSInputError, match=r"o\.exr would be written by .*f\.exr and .*f\.EXR"):
        process_frames([a, b], "burley", MAT, outputs=[tmp_path / "o.exr"] * 2, samples=4, progress=False)
    assert not (tmp_path / "o.exr").exists()
    # the CLI: non-zero exit before any write, both inputs named
    rc = main(["apply", str(a), str(b), "--out-dir", str(out), "--technique", "burley", "--d-mm", "1,1,1"])
    err = capsys.readouterr().err
    assert rc == 2 and "f.exr and" in err and "f.EXR" in err
    assert not out.exists() or list(out.rglob("*")) == []


def test_output_equal_to_an_input_is_refused(frames, tmp_path, capsys):
    from sss_jax.cli import main

    src = copy_frame(frames, "f2.exr", tmp_path / "in" / "frame.exr")
    before = src.read_bytes()
    rc = main(["apply", str(src), "-o", str(src), "--technique", "burley", "--d-mm", "1,1,1"])
    assert rc == 2 and "is the input" in capsys.readouterr().err
    # the same file through another spelling of its path, and --out-dir onto the inputs' own folder
    rc = main(["apply", str(src), "-o", str(tmp_path / "in" / ".." / "in" / "frame.exr"), "--technique", "burley",
               "--d-mm", "1,1,1"])
    assert rc == 2 and "is the input" in capsys.readouterr().err
    with pytest.raises(_io.SSSInputError, match="is the input"):
        process_frames(src, "burley", MAT, out_dir=tmp_path / "in", samples=4, progress=False)
    assert src.read_bytes() == before
    assert sorted(p.name for p in (tmp_path / "in").iterdir()) == ["frame.exr"]
    # and under another name: a hard link to it (was refused as an output "made from something other than sss_jax")
    link = tmp_path / "out" / "frame.exr"
    link.parent.mkdir()
    os.link(src, link)
    with pytest.raises(_io.SSSInputError, match=r"output .*out/frame.exr is the input .*in/frame.exr under another "
                                                r"name \(a hard link\)"):
        process_frames(src, "burley", MAT, out_dir=tmp_path / "out", samples=4, progress=False, overwrite=True)
    assert src.read_bytes() == before


def test_an_output_made_from_another_input_is_not_overwritten(frames, tmp_path):
    # two runs into one folder, each with one input called beauty.exr from another shot
    a = copy_frame(frames, "f0.exr", tmp_path / "a" / "beauty.exr")
    b = copy_frame(frames, "f3.exr", tmp_path / "b" / "beauty.exr")
    out = tmp_path / "out"
    assert process_frames(a, "burley", MAT, out_dir=out, samples=4, progress=False, devices=jax.devices()[:1]).ok
    first = (out / "beauty.exr").read_bytes()
    with pytest.raises(_io.SSSInputError, match=r"beauty.exr exists and was made from .*a/beauty.exr, not .*b/beauty"):
        process_frames(b, "burley", MAT, out_dir=out, samples=4, progress=False, devices=jax.devices()[:1])
    assert (out / "beauty.exr").read_bytes() == first
    r = process_frames(b, "burley", MAT, out_dir=out, samples=4, progress=False, devices=jax.devices()[:1],
                       overwrite=True)
    assert r.ok and (out / "beauty.exr").read_bytes() != first


def test_a_file_at_an_output_path_that_is_not_an_exr_is_not_overwritten(frames, tmp_path):
    # someone's notes (or a PNG) named like the output: it cannot be read, so it was taken for an output to recompute
    # and replaced without --overwrite. An empty file holds nothing to lose, and a damaged EXR is recomputed (resume)
    out = tmp_path / "out"
    out.mkdir()
    (out / "f0.exr").write_text("my notes on this shot")
    with pytest.raises(_io.SSSInputError, match=r"f0.exr exists and is not an EXR \(21 bytes\)"):
        process_frames(str(frames / "f0.exr"), "burley", MAT, out_dir=out, samples=4, progress=False,
                       devices=jax.devices()[:1])
    assert (out / "f0.exr").read_text() == "my notes on this shot"
    (out / "f0.exr").write_bytes(b"")
    assert process_frames(str(frames / "f0.exr"), "burley", MAT, out_dir=out, samples=4, progress=False,
                          devices=jax.devices()[:1]).ok
    assert _io.exr_is_complete(out / "f0.exr")


def test_a_file_created_meanwhile_is_not_replaced(tmp_path):
    # the placement another process could race with: the write of a new output fails rather than replace
    dst = tmp_path / "o.exr"
    _io.write_exr(dst, np.zeros((2, 2, 3), np.float32))
    before = dst.read_bytes()
    with pytest.raises(_io.SSSInputError, match="created by another process"):
        _io.write_exr(dst, np.ones((2, 2, 3), np.float32), overwrite=False)
    assert dst.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["o.exr"]


def test_two_processes_share_one_output_folder(frames, tmp_path):
    # jax.distributed's processes each take their share and keep their own manifest; together they write each
    # frame once
    results = [process_frames(str(frames / "*.exr"), "burley", MAT, out_dir=tmp_path, samples=8, progress=False,
                              devices=jax.devices()[:1], process_index=i, process_count=2) for i in range(2)]
    assert [len(r.frames) for r in results] == [3, 2] and all(r.ok for r in results)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == [f"f{i}.exr" for i in range(5)] + ["sss_jax_manifest.0.json", "sss_jax_manifest.1.json"]
    done = [f["input"] for i in range(2) for f in json.loads((tmp_path / f"sss_jax_manifest.{i}.json").read_text())
            ["frames"]]
    assert sorted(pathlib.Path(d).name for d in done) == [f"f{i}.exr" for i in range(5)]


def test_resume_skips_exactly_the_frames_made_the_same_way(frames, tmp_path):
    src = tmp_path / "src"
    for i in range(3):
        copy_frame(frames, f"f{i}.exr", src / f"f{i}.exr")
    out = tmp_path / "out"
    run = lambda mat, **kw: process_frames(str(src / "*.exr"), "burley", mat, out_dir=out, samples=4, progress=False,
                                           devices=jax.devices()[:1], **kw)
    assert run(MAT).ok
    before = {p.name: p.read_bytes() for p in out.glob("*.exr")}
    again = run(MAT)
    # every frame skipped: nothing read, nothing compiled, the files untouched
    assert [f.status for f in again.frames] == ["skipped"] * 3 and again.compilations == 0
    assert {p.name: p.read_bytes() for p in out.glob("*.exr")} == before
    book = json.loads((out / MANIFEST_NAME).read_text())
    assert [f["status"] for f in book["frames"]] == ["skipped"] * 3 and book["state"] == "complete"
    # another material: nothing is skipped (before, an existing output counted as finished whatever made it)
    other = sj.BurleyMaterial(MAT.albedo, MAT.d_mm * 2)
    changed = run(other)
    assert [f.status for f in changed.frames] == ["done"] * 3
    assert all((out / n).read_bytes() != before[n] for n in before)
    # a changed input (new mtime and size) is recomputed, the others skipped
    copy_frame(frames, "f4.exr", src / "f1.exr")
    assert [f.status for f in run(other).frames] == ["skipped", "done", "skipped"]
    # a damaged output is recomputed
    (out / "f2.exr").write_bytes((out / "f2.exr").read_bytes()[:200])
    assert [f.status for f in run(other).frames] == ["skipped", "skipped", "done"]
    assert _io.exr_is_complete(out / "f2.exr")
    # resume=False computes everything
    assert [f.status for f in run(other, resume=False).frames] == ["done"] * 3


def test_outputs_made_under_an_older_reading_of_the_files_are_computed_again(frames, tmp_path, monkeypatch):
    # the same file and arguments can read as another frame when the reader changes (2026-12-06: a Blender frame
    # without a unit in metres, not mm): an output made under the older reading is not kept on resume
    src = tmp_path / "src"
    copy_frame(frames, "f0.exr", src / "f0.exr")
    run = lambda: process_frames(str(src / "*.exr"), "burley", MAT, out_dir=tmp_path / "out", samples=4,
                                 progress=False, devices=jax.devices()[:1])
    assert run().ok
    assert [f.status for f in run().frames] == ["skipped"]
    monkeypatch.setattr(_io, "READER_REVISION", _io.READER_REVISION + 1)
    assert [f.status for f in run().frames] == ["done"]


@pytest.mark.parametrize("devices", [1, 4])
def test_an_input_rewritten_after_its_read_is_recomputed_on_resume(frames, tmp_path, monkeypatch, devices):
    # the output's record stamps its input (path, size, mtime) as it was when the frame was read; an input rewritten
    # after that (a re-render landing while the batch runs) must not pass for the one the output was made from.
    # Before, the run kept only the last two records, and a frame that waited in a compute thread (one device) or
    # in a group (four) had its record computed again at its write, stamping the new file: resume then kept the
    # output of the old pixels
    import sss_jax._batch as batch

    src = tmp_path / "src"
    for i in range(4):
        copy_frame(frames, f"f{i}.exr", src / f"f{i}.exr")
    real_read, rewritten = batch._read_image, []

    def read_then_rerender(path):
        decoded = real_read(path)
        path = pathlib.Path(path)
        if path.name in ("f1.exr", "f2.exr") and path.name not in rewritten:
            rewritten.append(path.name)
            mtime = path.stat().st_mtime_ns
            copy_frame(frames, "f4.exr", path)  # other pixels
            os.utime(path, ns=(mtime + 10**9, mtime + 10**9))
        return decoded

    monkeypatch.setattr(batch, "_read_image", read_then_rerender)
    out = tmp_path / "out"
    run = lambda: process_frames(str(src / "*.exr"), "separable", MAT, out_dir=out, taps=9, progress=False,
                                 devices=jax.devices()[:devices])
    assert run().ok and sorted(rewritten) == ["f1.exr", "f2.exr"]
    for name in ("f1.exr", "f2.exr"):  # each output records the input it was made from, not the one there now
        recorded = int(_io.read_header(out / name)[0]["sss_jax:input_mtime_ns"])
        assert recorded < (src / name).stat().st_mtime_ns
    monkeypatch.setattr(batch, "_read_image", real_read)
    statuses = {pathlib.Path(f.input).name: f.status for f in run().frames}  # several devices: groups' order
    assert statuses == {"f0.exr": "skipped", "f1.exr": "done", "f2.exr": "done", "f3.exr": "skipped"}


def test_lengths_given_as_numpy_scalars_run_and_bad_ones_are_refused(frames, tmp_path):
    # a focal length computed from a camera array arrives as a NumPy scalar: the resume record's JSON takes it as a
    # float (before, the batch died on its first frame with a TypeError, the manifest left "interrupted")
    focal = _io.read_header(frames / "f0.exr")[0]["sss_jax:focal_px"]
    run = lambda **kw: process_frames(str(frames / "f0.exr"), "separable", MAT, out_dir=tmp_path / "out", taps=9,
                                      progress=False, devices=jax.devices()[:1], **kw)
    assert run(focal_px=np.float32(focal), mm_per_unit=np.float64(10.0)).ok
    for bad in (0.0, -3.0, True, float("nan")):
        with pytest.raises(ValueError, match="focal_px must be a positive number"):
            run(focal_px=bad, overwrite=True)


def test_a_sidecar_whose_values_are_not_numbers_fails_its_frame(frames, tmp_path):
    # an exporter may name the camera ("camera": "Camera.001") or write a scale as a list: that frame fails with
    # the sidecar named, the others complete (before, an AttributeError or TypeError ended the whole batch)
    src = tmp_path / "src"
    src.mkdir()
    b = sj.demo_scene(40, 48).buffers
    channels = {"R": np.asarray(b.irradiance[..., 0]), "G": np.asarray(b.irradiance[..., 1]),
                "B": np.asarray(b.irradiance[..., 2]), "Z": np.asarray(b.depth)}
    for i in range(4):  # no focal length in the header: the sidecar's is the one
        _io.write_exr(src / f"f{i}.exr", channels, attributes={"sss_jax:mm_per_unit": 10.0})
    (src / "f0.json").write_text(json.dumps({"camera": {"focal_px": 60.0}}))
    (src / "f1.json").write_text(json.dumps({"camera": "Camera.001"}))
    (src / "f2.json").write_text(json.dumps({"camera": {"focal_px": "wide"}}))
    # a resolution of one number (before, an IndexError building the message ended the whole batch)
    (src / "f3.json").write_text(json.dumps({"camera": {"lens_mm": 50, "sensor_width_mm": 36}, "resolution": [48]}))
    r = process_frames(str(src / "*.exr"), "separable", MAT, out_dir=tmp_path / "out", taps=9, progress=False,
                       devices=jax.devices()[:1])
    assert [f.status for f in r.frames] == ["done", "failed", "failed", "failed"]
    assert "no focal length" in r.frames[1].message
    assert "camera.focal_px of f2.json is 'wide', not a number" in r.frames[2].message
    assert "resolution must be [width, height], got [48]" in r.frames[3].message
    with pytest.raises(_io.SSSInputError, match="f2.exr: focal_px from camera.focal_px of f2.json"):
        _io.read_frame(src / "f2.exr")


def test_any_error_reading_a_frame_fails_that_frame_and_the_batch_goes_on(frames, tmp_path, monkeypatch):
    # the reader's errors of any type, not only the OSError and ValueError it raises on purpose: before, another
    # type (an IndexError of a sidecar's reading) ended the whole batch, the frames after it never run and the
    # manifest left "interrupted"
    import sss_jax._batch as batch

    decoded = batch._frame_from_decoded

    def flaky(path, *args, **kwargs):
        if pathlib.Path(path).name == "f1.exr":
            raise KeyError("a channel the reader did not expect")
        return decoded(path, *args, **kwargs)

    monkeypatch.setattr(batch, "_frame_from_decoded", flaky)
    out = tmp_path / "out"
    r = process_frames([str(frames / f"f{i}.exr") for i in range(3)], "separable", MAT, out_dir=out, taps=9,
                       progress=False, devices=jax.devices()[:1])
    assert [f.status for f in r.frames] == ["done", "failed", "done"]
    assert "f1.exr" in r.frames[1].message and "KeyError" in r.frames[1].message
    book = json.loads((out / MANIFEST_NAME).read_text())
    assert book["state"] == "complete"
    assert [f["status"] for f in sorted(book["frames"], key=lambda f: f["input"])] == ["done", "failed", "done"]


def test_a_half_outputs_clamp_is_in_the_frames_warnings_and_the_manifest(tmp_path):
    # the writer thread's warning (values beyond half's range written as 65504) was printed but missing from the
    # frame's result and its manifest entry, where every other warning of the frame is (found by a review, 2026-12-07)
    src = tmp_path / "bright.exr"
    sc = sj.demo_scene(20, 24)
    b = sc.buffers
    _io.write_exr(src, {**{c: np.asarray(b.irradiance[..., i]) * 1e6 for i, c in enumerate("RGB")},
                        "Z": np.asarray(b.depth), "id": np.asarray(b.material_id).astype(np.float32)},
                  attributes={"sss_jax:focal_px": float(sc.camera.focal_px), "sss_jax:mm_per_unit": 10.0})
    out = tmp_path / "out"
    r = process_frames(str(src), "separable", MAT, out_dir=out, taps=9, half=True, progress=False,
                       devices=jax.devices()[:1])
    (frame,) = r.frames
    assert frame.status == "done"
    said = [w for w in frame.warnings if "beyond half's range" in w]
    assert len(said) == 1 and "written as +-65504" in said[0] and said[0] in frame.message
    (entry,) = json.loads((out / MANIFEST_NAME).read_text())["frames"]
    assert said[0] in entry["warnings"]
    channels, _, _ = _io.read_channels(out / "bright.exr")
    assert max(float(np.abs(channels[c]).max()) for c in "RGB") == 65504.0


def test_a_temporary_that_cannot_be_stated_is_left_alone(tmp_path):
    # an old-style temporary that is gone between the folder's listing and its stat (here a dangling link): before,
    # the sweep read a verdict it had never set (UnboundLocalError) and the batch stopped before its first frame
    from sss_jax._batch import remove_stale_temporaries

    (tmp_path / ".f0.exr.abcd1234.tmp.exr").symlink_to(tmp_path / "gone")
    assert remove_stale_temporaries([tmp_path / "f0.exr"]) == []


def test_unwritable_output_folder_is_refused_before_any_frame(frames, tmp_path, readonly_dir):
    with pytest.raises(_io.SSSInputError, match="not writable"):
        process_frames(str(frames / "f0.exr"), "burley", MAT, out_dir=readonly_dir, samples=4,
                       progress=False)
    blocked = tmp_path / "blocked"
    (blocked / "f0.exr").mkdir(parents=True)
    with pytest.raises(_io.SSSInputError, match="f0.exr: output path is a directory"):
        process_frames(str(frames / "f0.exr"), "burley", MAT, out_dir=blocked, samples=4, progress=False)
    assert sorted(p.name for p in blocked.iterdir()) == ["f0.exr"]


def test_the_demo_refuses_a_folder_it_cannot_write_before_rendering(readonly_dir, monkeypatch, capsys):
    # an existing folder that takes no file: before, the demo rendered every technique and then stopped with a
    # PermissionError traceback at its first image (found by a review, 2026-12-07)
    import sss_jax._demo as demo
    from sss_jax.cli import main

    monkeypatch.setattr(demo, "run_demo", lambda **kw: pytest.fail("rendered before the folder was checked"))
    assert main(["demo", "--out", str(readonly_dir), "--size", "16x12"]) == 2
    assert "output directory is not writable" in capsys.readouterr().err


@pytest.fixture
def readonly_dir(tmp_path):
    """A folder no file can be created in: permission bits where they bind; as root (who ignores them) sysfs,
    which refuses new files to everyone."""
    import os
    import tempfile

    if os.geteuid() != 0:
        d = tmp_path / "ro"
        d.mkdir()
        d.chmod(0o555)
        yield d
        d.chmod(0o755)
        return
    d = pathlib.Path("/sys/kernel")
    try:
        tempfile.TemporaryFile(dir=d).close()
    except OSError:
        yield d
        return
    pytest.skip("no folder here refuses new files to root")


# ------------------------------------------------------------------------------------------------------------------
# the technique's ranges, bounded work, tiles
# ------------------------------------------------------------------------------------------------------------------


def test_sta_ranges_are_checked_before_any_frame(frames, tmp_path):
    sta = (sj.STAParams(), sj.DirectionalLight([0.3, -0.4, 0.9]))
    with pytest.raises(ValueError, match=r"sta: albedo must be 3 values in \[0, 1\]"):
        process_frames(str(frames / "*.exr"), "sta", sta, out_dir=tmp_path / "o", sta_albedo=(2.0, 0.5, 0.5))
    with pytest.raises(ValueError, match="sta: thickness must be >= 0"):
        process_frames(str(frames / "*.exr"), "sta", sta, out_dir=tmp_path / "o", sta_thickness=-3.0)
    with pytest.raises(ValueError, match="sta: thickness must be >= 0"):
        process_frames(str(frames / "*.exr"), "sta", sta, out_dir=tmp_path / "o", sta_thickness=float("nan"))
    with pytest.raises(ValueError, match="scale must be finite"):
        sj.STAParams(scale=float("inf"))
    with pytest.raises(ValueError, match="light colour must be finite"):
        sj.DirectionalLight([0.0, 0.0, 1.0], colour=(1.0, float("inf"), 1.0))
    assert not (tmp_path / "o").exists()


def burley_r999() -> float:
    """Radius (units of d) holding 99.9% of the normalised Burley profile's energy: its CDF is
    1 - (exp(-r/d) + 3 exp(-r/(3d))) / 4 (Christensen & Burley 2015), solved here by bisection."""
    lo, hi = 0.0, 100.0
    for _ in range(200):
        mid = (lo + hi) / 2
        if 1 - (np.exp(-mid) + 3 * np.exp(-mid / 3)) / 4 < 0.999:
            lo = mid
        else:
            hi = mid
    return lo


def test_the_clamps_largest_footprint_is_the_per_pixel_maximum():
    # the clamp takes each material row's nearest surface; the reference is the per-pixel plane it replaced:
    # px = d[row] * (focal / mm_per_unit / depth) in float32 over the SSS pixels whose px * r99 reaches 0.5 px
    from sss_jax._batch import _largest_px
    from sss_jax._techniques._common import MIN_FOOTPRINT_PX

    rng = np.random.default_rng(7)
    for _ in range(200):
        h, w = (int(n) for n in rng.integers(1, 24, 2))
        count = int(rng.integers(1, 4))
        depth = rng.uniform(0.5, 300.0, (h, w)).astype(np.float32)
        depth[rng.random((h, w)) < 0.2] = np.inf
        depth[rng.random((h, w)) < 0.05] = 0.0
        depth[rng.random((h, w)) < 0.03] = np.nan  # renderers' holes: not SSS pixels
        depth[rng.random((h, w)) < 0.03] = -np.inf
        ids = rng.integers(0, count + 2, (h, w)).astype(np.int32) if rng.random() < 0.8 else None
        camera = sj.Camera(float(rng.uniform(10, 2000)), float(rng.uniform(0.1, 20)))
        per_row = rng.uniform(0.0, 5.0, count) * (rng.random(count) > 0.2)
        r99 = float(rng.choice([0.01, 1.0, 12.95]))
        valid = np.isfinite(depth) & (depth > 0) & (True if ids is None else ids > 0)
        rows = np.zeros((h, w), int) if ids is None or count == 1 else np.clip(ids - 1, 0, count - 1)
        ppm = np.divide(np.float32(camera.focal_px / camera.mm_per_unit), depth, out=np.zeros_like(depth),
                        where=valid)
        px = per_row.astype(np.float32)[rows] * ppm
        active = valid & (px * r99 >= MIN_FOOTPRINT_PX) & (px > 0)
        want = float(np.max(px, where=active, initial=0.0))
        frame = types.SimpleNamespace(depth=depth, material_id=ids)  # what the clamp reads of the buffers
        assert _largest_px(frame, camera, per_row, active_r99=r99) == want


def test_the_work_estimate_does_not_learn_from_a_frame_that_compiled():
    # the first frame of a shape compiles (~1 s against ~10 ms of work at 256x256): taken as work, it sent the
    # next frames into pieces (each compiling again: seconds per frame); the estimate learns from the frames after it
    from sss_jax._batch import _Cost, _seconds_per_px

    tech = sj.technique("burley", samples=32)
    cost = _Cost()
    figure = _seconds_per_px(tech)
    cost.measured(tech, 256 * 256, 1.0, shape=(256, 256), calls=1)  # the compile
    assert cost.per_px(tech) == figure
    cost.measured(tech, 256 * 256, 0.02, shape=(256, 256), calls=1)
    assert cost.per_px(tech) == pytest.approx(0.02 / (256 * 256))
    cost.measured(tech, 512 * 512, 3.0, shape=(512, 512), calls=1)  # another shape compiles too
    assert cost.per_px(tech) == pytest.approx(0.02 / (256 * 256))


def test_samples_beyond_the_footprint_are_clamped_with_a_warning(frames, tmp_path):
    f = _io.read_frame(frames / "f0.exr")
    # the footprint: the 99.9%-energy radius of the widest d at the nearest SSS pixel, as an area in pixels
    sss = np.isfinite(f.depth) & (f.material_id > 0)
    rows = np.clip(f.material_id - 1, 0, 2)
    d_px = np.asarray(MAT.d_mm, np.float64).max(-1)[rows] * f.focal_px / (f.depth * 10.0)
    pixels = math.pi * (burley_r999() * d_px[sss].max()) ** 2
    bound = 1 << math.ceil(math.log2(pixels))
    assert bound < 10**7
    with pytest.warns(UserWarning, match=f"samples 10000000 clamped to {bound}: the footprint has"):
        r = process_frames(str(frames / "f0.exr"), "burley", MAT, out_dir=tmp_path, samples=10**7, progress=False,
                           devices=jax.devices()[:1])
    assert r.ok and f"clamped to {bound}" in r.frames[0].message
    single = np.asarray(sj.burley(f.to_buffers(), MAT, sj.Camera(f.focal_px, 10.0), samples=bound))
    np.testing.assert_allclose(read_rgb(tmp_path / "f0.exr"), single, rtol=1e-5, atol=1e-6)
    book = json.loads((tmp_path / MANIFEST_NAME).read_text())
    assert f"clamped to {bound}" in book["frames"][0]["message"]


def test_a_burley_material_under_a_pixel_says_the_frame_keeps_its_local_shading(frames, tmp_path):
    # d typed in metres where millimetres belong (0.003 for 3 mm): no pixel's footprint reaches a neighbour, and the
    # warning says what the frame gets and which units the lengths are in (before: "the footprint has 0 pixels, more
    # samples cannot help; it runs 1 samples")
    tiny = sj.BurleyMaterial(MAT.albedo, np.asarray(MAT.d_mm) * 1e-3)
    with pytest.warns(UserWarning, match=r"samples 32 clamped to 1: no pixel's footprint reaches a neighbouring "
                                         r"pixel: the frame keeps its local shading \(the widest d 0.0035 mm\)"):
        r = process_frames(str(frames / "f0.exr"), "burley", tiny, out_dir=tmp_path, progress=False,
                           devices=jax.devices()[:1])
    assert r.ok and "it runs 1 sample," in r.frames[0].message, r.frames[0].message


def test_a_separable_kernel_under_a_pixel_clamps_to_its_centre_tap(frames, tmp_path):
    # a kernel that reaches no neighbouring pixel (d far under a pixel's width): the clamp once gave 2 taps, an even
    # count the pass then refused, so the frame failed ("taps must be an odd positive integer, got 2")
    f = _io.read_frame(frames / "f0.exr")
    tiny = sj.BurleyMaterial(MAT.albedo, np.full((3, 3), 1e-4, np.float32))
    assert sj.technique("separable", taps=25).reach_px(f.to_buffers(), tiny, sj.Camera(f.focal_px, 10.0)) == 0
    with pytest.warns(UserWarning, match="taps 25 clamped to 1: a pass reaches no neighbouring pixel: the frame "
                                         "keeps its local shading \\(the widest d 0.0001 mm\\); if that is not meant, "
                                         "the material's lengths are in millimetres"):
        r = process_frames(str(frames / "f0.exr"), "separable", tiny, out_dir=tmp_path, progress=False,
                           devices=jax.devices()[:1])
    assert r.ok, r.frames[0].message
    single = np.asarray(sj.separable(f.to_buffers(), tiny, sj.Camera(f.focal_px, 10.0), taps=1))
    np.testing.assert_allclose(read_rgb(tmp_path / "f0.exr"), single, rtol=1e-6, atol=1e-7)


def test_a_count_of_taps_typed_far_too_large_is_clamped_without_building_its_kernel(frames, tmp_path, monkeypatch):
    # the reach (the outermost tap) is the same for every count above 1; it was read off the kernel of the count
    # asked for, so --taps 200001 pre-integrated 200001 taps per material (50 s and 5.9 GB at 256x192) before the
    # clamp cut them to what the frame can use
    f = _io.read_frame(frames / "f0.exr")
    b, cam = f.to_buffers(), sj.Camera(f.focal_px, 10.0)
    built = []
    kernels = sj.BurleyMaterial.separable_kernels
    monkeypatch.setattr(sj.BurleyMaterial, "separable_kernels",
                        lambda self, taps, dtype: built.append(taps) or kernels(self, taps, dtype))
    reach = sj.technique("separable", taps=25).reach_px(b, MAT, cam)
    assert reach > 1 and sj.technique("separable", taps=200001).reach_px(b, MAT, cam) == reach
    assert max(built) <= 25, built
    bound = next(2**k + 1 for k in range(30) if 2**k >= 2 * reach)  # the next 2^k + 1 above the pixels a pass reads
    with pytest.warns(UserWarning, match=f"taps 200001 clamped to {bound}: a pass reaches {2 * reach + 1} pixels"):
        r = process_frames(str(frames / "f0.exr"), "separable", MAT, out_dir=tmp_path, progress=False, taps=200001,
                           devices=jax.devices()[:1])
    assert r.ok and max(built) <= bound, (r.frames[0].message, max(built))


STA_MATERIAL = (sj.STAParams(thickness_mm=2.0), sj.DirectionalLight([0.3, -0.4, 0.9]))


# tiles under the DEFAULTS: each tile is told its origin in the frame and the frame's shape, so the rotation hash and
# the frame border are the frame's; a technique that cannot place a tile (no origin/frame_shape options yet) runs
# the frame whole
@pytest.mark.parametrize("technique, material, options, direct", [
    ("burley", MAT, dict(samples=8), lambda b, c: sj.burley(b, MAT, c, samples=8, seed=frame_seed(0, 1))),
    ("separable", MAT, dict(taps=9), lambda b, c: sj.separable(b, MAT, c, taps=9)),
    ("reference", MAT, dict(radius_px=4), lambda b, c: sj.reference(b, MAT, c, radius_px=4)),
    ("sta", STA_MATERIAL, dict(sta_thickness=0.5),
     lambda b, c: sj.translucency(b, STA_MATERIAL[0], c, STA_MATERIAL[1], thickness=0.5)),
])
def test_tiles_give_the_untiled_frame_under_the_defaults(frames, tmp_path, monkeypatch, technique, material, options,
                                                         direct):
    import sss_jax._batch as batch

    tiles = []
    real = batch._run_tiled

    def spy(tech, frame, use_albedo, mat, camera, plan, on_tile):
        out = real(tech, frame, use_albedo, mat, camera, plan, on_tile)  # raises where it cannot place a tile
        tiles.append(plan.layout)
        return out

    monkeypatch.setattr(batch, "_run_tiled", spy)
    whole = process_frames(str(frames / "f1.exr"), technique, material, out_dir=tmp_path / "whole", progress=False,
                           devices=jax.devices()[:1], **options)
    assert whole.ok and tiles == []
    tiled = process_frames(str(frames / "f1.exr"), technique, material, out_dir=tmp_path / "tiled", progress=False,
                           tile_pixels=24 * 24, devices=jax.devices()[:1], **options)
    assert tiled.ok
    # where the technique places tiles it did run in tiles (else the frame ran whole: the same pixels either way)
    assert all(ty * tx < 40 * 48 for ty, tx in tiles)
    out_tiled, out_whole = read_rgb(tmp_path / "tiled" / "f1.exr"), read_rgb(tmp_path / "whole" / "f1.exr")
    assert np.max(np.abs(out_tiled - out_whole)) <= 1e-4
    f = _io.read_frame(frames / "f1.exr")
    # independent check: the public technique on the whole frame, with the frame's seed (the file's frame number 1)
    single = np.asarray(direct(f.to_buffers(), sj.Camera(f.focal_px, 10.0)))
    np.testing.assert_allclose(out_whole, single, rtol=1e-5, atol=1e-6)
    header = _io.read_header(tmp_path / "tiled" / "f1.exr")[0]
    rules = json.loads(header["sss_jax:rules"])  # the rules that ran are in the header
    for name, value in {"samples": 8, "taps": 9, "radius_px": 4, "thickness": 0.5, "border": "renormalise",
                        "pattern": "rotated"}.items():
        if name in rules:
            assert rules[name] == value
    # every technique that can place a tile runs in tiles; separable's default formulation on a CPU (banded: its
    # reach levels are its buffer's) refuses a tile, so its frames run whole there (the same pixels)
    places = technique != "separable" or jax.default_backend() != "cpu"
    assert bool(tiles) == places, (technique, tiles)
    if technique in ("sta", "burley", "reference"):  # these place tiles now
        assert tiles, "expected tiles"


def test_apply_in_tiles_gives_the_untiled_frame(frames, tmp_path, monkeypatch):
    # the same comparison through the command line: the reference (it places tiles now) with the leaving border,
    # whose frame edge the tiles must take from the frame (the default border is compared through process_frames)
    import sss_jax._batch as batch
    from sss_jax.cli import main

    layouts = []
    real = batch._run_tiled
    monkeypatch.setattr(batch, "_run_tiled", lambda tech, frame, *a: layouts.append(a[3].layout) or real(
        tech, frame, *a))
    args = ["--technique", "reference", "--radius-px", "4", "--albedo", "0.8,0.6,0.5", "--d-mm", "3,1.4,0.8",
            "--border", "leaves"]
    assert main(["apply", str(frames / "f1.exr"), "-o", str(tmp_path / "whole.exr")] + args) == 0
    assert main(["apply", str(frames / "f1.exr"), "-o", str(tmp_path / "tiled.exr"), "--tile-pixels", "576"]
                + args) == 0
    whole, tiled = read_rgb(tmp_path / "whole.exr"), read_rgb(tmp_path / "tiled.exr")
    assert np.max(np.abs(tiled - whole)) <= 1e-4
    assert np.max(np.abs(tiled - read_rgb(frames / "f1.exr"))) > 1e-2  # it scattered
    assert layouts and all(ty * tx < 40 * 48 for ty, tx in layouts)  # in tiles


# ------------------------------------------------------------------------------------------------------------------
# long frames: in pieces (tiles, the technique's own pieces), with progress and an estimate; a signal stops them
# within about one call
# ------------------------------------------------------------------------------------------------------------------


def test_burley_frames_split_into_pieces_that_give_the_whole_call(frames):
    f = _io.read_frame(frames / "f1.exr")
    b, cam = f.to_buffers(), sj.Camera(f.focal_px, 10.0)
    t = sj.Burley(samples=8, frames=6, seed=4_000_000_000)  # a seed near 2^32: the shifted seeds wrap
    pieces = t.pieces(4)
    assert [p.frames for p, _ in pieces] == [2, 2, 2] and math.isclose(sum(w for _, w in pieces), 1.0)
    summed = sum(w * np.asarray(p(b, MAT, cam), np.float64) for p, w in pieces)
    whole = np.asarray(t(b, MAT, cam))
    assert np.abs(summed - whole).max() <= 1e-5  # frame k of a piece is frame a + k of the whole: same rotations
    assert np.abs(np.asarray(pieces[1][0].replace(seed=t.seed)(b, MAT, cam)) - np.asarray(
        pieces[1][0](b, MAT, cam))).max() > 1e-3  # (the shifted seed matters)
    # what does not split: one frame, the fixed spiral (its frame 0 is unturned whatever the seed)
    assert sj.Burley(frames=1).pieces(4) is None and sj.Burley(pattern="fixed", frames=6).pieces(4) is None
    # spreading moves samples into frames, keeping at least 64 a frame; the fixed spiral and small counts stay
    assert sj.Burley(samples=1024).spread(10).options() == sj.Burley(samples=64, frames=16).options()
    assert sj.Burley(samples=32).spread(10) == sj.Burley(samples=32)
    assert sj.Burley(samples=1024, pattern="fixed").spread(10) == sj.Burley(samples=1024, pattern="fixed")


def test_a_long_frame_runs_in_pieces_with_progress_and_gives_the_whole_frame(frames, tmp_path, monkeypatch):
    # a work bound of 0.1 ms per call (SSS_JAX_CALL_SECONDS) makes this small frame long: 8 TAA frames in pieces
    monkeypatch.setenv("SSS_JAX_CALL_SECONDS", "1e-4")
    lines = []
    r = process_frames(str(frames / "f1.exr"), "burley", MAT, out_dir=tmp_path, samples=8, progress=False,
                       technique_options={"frames": 8}, devices=jax.devices()[:1], on_progress=lines.append)
    assert r.ok
    f = _io.read_frame(frames / "f1.exr")
    whole = np.asarray(sj.burley(f.to_buffers(), MAT, sj.Camera(f.focal_px, 10.0), samples=8, frames=8,
                                 seed=frame_seed(0, 1)))
    np.testing.assert_allclose(read_rgb(tmp_path / "f1.exr"), whole, rtol=1e-5, atol=1e-6)
    assert re.match(r"f1\.exr \(48x40\): \d+ calls \(\d+ tile\(s\) x \d+ piece\(s\)\), about .* by the estimate",
                    lines[0]), lines
    assert re.match(r"f1\.exr \(48x40\): (\d+) of \1 calls \(100%\), .*, about 0 s left", lines[-1]), lines
    rules = json.loads(_io.read_header(tmp_path / "f1.exr")[0]["sss_jax:rules"])
    assert (rules["samples"], rules["frames"]) == (8, 8)  # exact pieces: the technique that ran is the one asked for
    monkeypatch.setenv("SSS_JAX_CALL_SECONDS", "soon")
    with pytest.raises(ValueError, match="SSS_JAX_CALL_SECONDS must be a positive number of seconds, got 'soon'"):
        process_frames(str(frames / "f1.exr"), "burley", MAT, out_dir=tmp_path / "x", samples=8, progress=False)


# the frames of the huge count's job: enough that the signal, sent after the first progress line, always lands mid-job
# (64 left ~1.4 s of work after that line, which a loaded machine finished before the signal came); the signal ends
# the child, so a longer job costs the test nothing
TAA_FRAMES = 1024


def _interruptible() -> None:
    """In the child, before it runs: SIGINT as a terminal's Ctrl-C delivers it. A process inherits an ignored SIGINT
    (a shell's background job, ``cmd &`` without job control, ignores it) and Python then installs no
    KeyboardInterrupt handler, so a suite started in the background had these tests' children deaf to the signal,
    whatever the library does (they failed so in a suite run started with ``nohup ... &``; CI runs in the
    foreground)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_apply_with_a_huge_count_says_the_clamp_and_estimate_shows_progress_and_stops_on_sigint(frames, tmp_path):
    # what a user did on the Blender frame (--samples 10000000: minutes on one frame, silent, deaf to Ctrl-C), on a
    # small frame made long by a small work bound per call (SSS_JAX_CALL_SECONDS)
    import os
    import subprocess
    import sys
    import threading
    import time

    src = copy_frame(frames, "f0.exr", tmp_path / "src" / "f0.exr")
    out = tmp_path / "out"
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=1", SSS_JAX_CALL_SECONDS="0.01",
               PYTHONPATH=str(pathlib.Path(__file__).resolve().parents[1]))
    child = subprocess.Popen([sys.executable, "-m", "sss_jax", "apply", str(src), "--out-dir", str(out),
                              "--technique", "burley", "--albedo", "0.8,0.6,0.5", "--d-mm", "3,1.4,0.8",
                              "--samples", "10000000", "--frames", str(TAA_FRAMES)], env=env, stderr=subprocess.PIPE,
                             text=True, preexec_fn=_interruptible)
    lines, progressed = [], threading.Event()

    def read():
        for line in child.stderr:
            lines.append(line)
            if " left" in line:
                progressed.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    assert progressed.wait(300), "".join(lines)[-3000:]
    child.send_signal(signal.SIGINT)
    sent = time.monotonic()
    child.wait(timeout=120)
    after = time.monotonic() - sent
    reader.join(10)
    text = "".join(lines)
    assert child.returncode == 130, text[-3000:]
    # the clamp said what runs and about how long, before the frame ran
    clamp = re.search(r"warning: .*samples 10000000 clamped to (\d+): .*; it runs (\d+) samples, (\d+) frames, about "
                      r"(.+) per frame on this machine .*, in (\d+) calls", text)
    assert clamp, text[-3000:]
    bound, samples, taa, calls = (int(clamp[i]) for i in (1, 2, 3, 5))
    assert samples * taa == bound * TAA_FRAMES and samples >= 64  # the same samples per pixel, spread over frames
    done = [int(m[1]) for m in re.finditer(rf"f0\.exr \(48x40\): (\d+) of {calls} calls", text)]
    assert done and max(done) < calls  # it stopped before finishing ...
    assert after < 60, after  # ... within about a call of the signal (loosely: the frame had seconds left)
    book = json.loads((out / MANIFEST_NAME).read_text())
    assert book["state"] == "interrupted" and [f["status"] for f in book["frames"]] == ["pending"]
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST_NAME]  # nothing half-written
    assert "interrupted: only complete frames were written" in text


# ------------------------------------------------------------------------------------------------------------------
# SIGINT and SIGTERM: the manifest lists exactly the frames complete on disk
# ------------------------------------------------------------------------------------------------------------------

CHILD = """
import sys, time
import sss_jax as sj
from sss_jax._batch import Interrupted, process_frames
mat = sj.BurleyMaterial([[0.8, 0.6, 0.5]] * 3, [[3.0, 1.4, 0.8], [2.2, 1.9, 1.6], [3.5, 2.4, 1.4]])
try:
    # each finished frame lingers inside the write's critical section: a signal arriving there must wait for the
    # manifest entry of the frame just written
    process_frames(sys.argv[1], "burley", mat, out_dir=sys.argv[2], samples=4, progress=False,
                   on_frame_done=lambda r: time.sleep(0.4))
except Interrupted as exc:
    sys.exit(128 + exc.signum)
"""


# frames of the signalled batch: the signal goes after the second is done and must find frames still pending (12
# of ~0.5 s each all finished before it on a loaded machine); the signal ends the child, so more frames cost nothing
SIGNAL_FRAMES = 60


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_manifest_after_a_signal_lists_exactly_the_complete_frames(frames, tmp_path, signum):
    import os
    import subprocess
    import sys
    import time

    src = tmp_path / "src"
    for i in range(SIGNAL_FRAMES):
        copy_frame(frames, f"f{i % 5}.exr", src / f"g{i:02d}.exr")
    out = tmp_path / "out"
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=1",
               PYTHONPATH=str(pathlib.Path(__file__).resolve().parents[1]))
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(src / "*.exr"), str(out)], env=env,
                             stderr=subprocess.PIPE, preexec_fn=_interruptible)
    book_path = out / MANIFEST_NAME
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and child.poll() is None:
        try:
            if sum(f["status"] == "done" for f in json.loads(book_path.read_text())["frames"]) >= 2:
                break
        except (OSError, ValueError):
            pass
        time.sleep(0.05)
    child.send_signal(signum)
    _, err = child.communicate(timeout=120)
    assert child.returncode == 128 + signum, err.decode()[-2000:]
    book = json.loads(book_path.read_text())
    assert book["state"] == "interrupted"
    done = {pathlib.Path(f["output"]).name for f in book["frames"] if f["status"] == "done"}
    on_disk = {p.name for p in out.iterdir() if p.name != MANIFEST_NAME}
    assert 2 <= len(done) < SIGNAL_FRAMES and done == on_disk  # no temporary files either
    assert all(_io.exr_is_complete(out / n) for n in on_disk)
    assert {f["status"] for f in book["frames"]} == {"done", "pending"}


# ------------------------------------------------------------------------------------------------------------------
# every file atomic, a full disk fails one frame (named), --resume verifies what it skips for, one true manifest,
# stale temporaries removed
# ------------------------------------------------------------------------------------------------------------------


def five_frames(frames, folder):
    for i in range(5):
        copy_frame(frames, f"f{i}.exr", folder / f"f{i}.exr")
    return folder


def temporaries(folder):
    return sorted(p.name for p in folder.iterdir() if ".tmp" in p.name)


def test_a_disk_filling_during_a_png_batch_fails_that_frame_and_resume_recomputes_it(frames, tmp_path, monkeypatch):
    import contextlib

    src = five_frames(frames, tmp_path / "src")
    out = tmp_path / "out"
    real = _io.atomic_path

    @contextlib.contextmanager
    def filling(path, **kw):
        # the disk fills while f2's preview is written: OpenImageIO's PNG writer reports nothing and the file ends
        # half way (what a 256 KiB tmpfs did), so only the check that the written file decodes can catch it
        with real(path, **kw) as tmp:
            yield tmp
            if pathlib.Path(path).name == "f2.png":
                data = tmp.read_bytes()
                tmp.write_bytes(data[: len(data) // 2])

    monkeypatch.setattr(_io, "atomic_path", filling)
    r = process_frames(str(src / "*.exr"), "burley", MAT, out_dir=out, png=True, samples=4, progress=False,
                       devices=jax.devices()[:1])
    assert [f.status for f in r.frames] == ["done", "done", "failed", "done", "done"]  # the batch went on
    assert "f2.png" in r.failed[0].message and "does not decode" in r.failed[0].message
    # no partial file: neither the broken preview nor an EXR of the failed frame nor a temporary
    names = sorted(p.name for p in out.iterdir())
    assert names == sorted([f"f{i}.{e}" for i in (0, 1, 3, 4) for e in ("exr", "png")] + [MANIFEST_NAME])
    book = json.loads((out / MANIFEST_NAME).read_text())
    entry = next(f for f in book["frames"] if f["output"].endswith("f2.exr"))
    assert entry["status"] == "failed" and "f2.png" in entry["message"]
    monkeypatch.setattr(_io, "atomic_path", real)
    # a preview broken behind the batch's back (another tool, a bad disk): --resume decodes it and recomputes
    (out / "f3.png").write_bytes((out / "f3.png").read_bytes()[:60])
    again = process_frames(str(src / "*.exr"), "burley", MAT, out_dir=out, png=True, samples=4, progress=False,
                           devices=jax.devices()[:1])
    assert [f.status for f in again.frames] == ["skipped", "skipped", "done", "done", "skipped"]
    assert all(_io.exr_is_complete(out / f"f{i}.{e}") for i in range(5) for e in ("exr", "png"))
    assert temporaries(out) == []


def test_a_real_full_file_system_names_the_file(frames, tmp_path):
    import os
    import subprocess

    src = five_frames(frames, tmp_path / "src")
    small = tmp_path / "small"
    small.mkdir()
    # a tmpfs of 48 KiB: a few frames' EXR and PNG fit, then every write fails (needs mount rights: root here)
    if os.geteuid() != 0 or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=48k", "tmpfs", str(small)],
                                           capture_output=True).returncode != 0:
        pytest.skip("cannot mount a small tmpfs here")
    try:
        r = process_frames(str(src / "*.exr"), "burley", MAT, out_dir=small, png=True, samples=4, progress=False,
                           devices=jax.devices()[:1])
        assert r.failed, "the file system never filled: make it smaller"
        for f in r.failed:
            assert pathlib.Path(f.output).stem in f.message  # the frame's file is named
        done = {pathlib.Path(f.output).stem for f in r.frames if f.status == "done"}
        for p in small.iterdir():  # what is there is whole: a complete frame's files, no partial file
            assert ".tmp" not in p.name
            if p.suffix in (".exr", ".png"):
                assert p.stem in done and _io.exr_is_complete(p)
    finally:
        subprocess.run(["umount", str(small)], check=True)


def test_a_preview_another_run_places_meanwhile_is_neither_replaced_nor_removed(frames, tmp_path, monkeypatch):
    # two runs into one folder with previews: the other run places this frame's preview and EXR while this one
    # writes its preview. Before, this run replaced the other's preview, lost the race for the EXR (refused, as it
    # should) and then removed "its" fresh preview: the other run's, whose EXR was left without one
    import sss_jax._batch as batch

    out = tmp_path / "out"
    out.mkdir()
    real_png = batch.write_png_preview

    def other_run_first(path, image, **kw):
        path = pathlib.Path(path)
        real_png(path, np.full_like(image, 0.25))
        _io.write_exr(path.with_suffix(".exr"), np.full_like(image, 0.25), attributes={"sss_jax:input": "other"})
        return real_png(path, image, **kw)

    monkeypatch.setattr(batch, "write_png_preview", other_run_first)
    r = process_frames(str(frames / "f0.exr"), "separable", MAT, out_dir=out, taps=9, png=True, progress=False,
                       manifest=False, devices=jax.devices()[:1])
    assert r.frames[0].status == "failed" and "f0.png: was created by another process" in r.frames[0].message
    assert sorted(p.name for p in out.iterdir()) == ["f0.exr", "f0.png"]
    assert _io.read_header(out / "f0.exr")[0]["sss_jax:input"] == "other"
    np.testing.assert_allclose(_io.read_frame(out / "f0.png", channel_map={"irradiance": ["R", "G", "B"],
                                                                           "depth": "R"}).irradiance,
                               np.round(np.asarray(_io.display_transform(np.full((40, 48, 3), 0.25))) * 255) / 255,
                               atol=1e-6)


def test_runs_that_spell_the_folder_differently_share_the_manifests_entries(frames, tmp_path, monkeypatch):
    # a run into "out" (relative) whose frame failed, then a run into the same folder spelled absolutely that
    # completes it: one entry per file, "done". Before, the entries were keyed by the path as spelled, and the
    # first run's "failed" stayed beside the second's "done" (the manifest saying a complete frame failed)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "in").mkdir()
    copy_frame(frames, "f0.exr", tmp_path / "in" / "f0.exr")
    (tmp_path / "in" / "f1.exr").write_bytes(b"not an exr")
    run = lambda inputs, out: process_frames(inputs, "separable", MAT, out_dir=out, taps=9, progress=False,
                                             devices=jax.devices()[:1])
    assert [f.status for f in run(["in/f0.exr", "in/f1.exr"], "out").frames] == ["done", "failed"]
    copy_frame(frames, "f1.exr", tmp_path / "in" / "f1.exr")
    again = run([str(tmp_path / "in" / "f0.exr"), str(tmp_path / "in" / "f1.exr")], tmp_path / "out")
    assert [f.status for f in again.frames] == ["skipped", "done"]
    book = json.loads((tmp_path / "out" / MANIFEST_NAME).read_text())
    assert sorted((f["output"], f["status"]) for f in book["frames"]) == [
        (str(tmp_path / "out" / "f0.exr"), "skipped"), (str(tmp_path / "out" / "f1.exr"), "done")]


def test_a_manifest_of_relative_entries_from_before_is_folded_into_one_entry_per_file(frames, tmp_path,
                                                                                      monkeypatch):
    # a manifest written before entries held absolute paths (outputs as the run spelled them, "out/f1.exr", relative
    # to a folder it did not record): a new run completing the failed frame leaves one entry per file, not the old
    # "failed" beside the new "done"; an entry of no output of this run stays as it was
    monkeypatch.chdir(tmp_path)
    (tmp_path / "in").mkdir()
    for name in ("f0.exr", "f1.exr"):
        copy_frame(frames, name, tmp_path / "in" / name)
    (tmp_path / "out").mkdir()
    old = {"state": "done", "runs": [{"run": "old", "state": "done"}], "frames": [
        {"input": "in/f1.exr", "output": "out/f1.exr", "status": "failed", "message": "x", "run": "old"},
        {"input": "in/g.exr", "output": "out/g.exr", "status": "done", "message": "", "run": "old"}]}
    (tmp_path / "out" / MANIFEST_NAME).write_text(json.dumps(old))
    r = process_frames([str(tmp_path / "in" / "f0.exr"), str(tmp_path / "in" / "f1.exr")], "separable", MAT,
                       out_dir=tmp_path / "out", taps=9, progress=False, devices=jax.devices()[:1])
    assert [f.status for f in r.frames] == ["done", "done"]
    book = json.loads((tmp_path / "out" / MANIFEST_NAME).read_text())
    assert sorted((f["output"], f["status"]) for f in book["frames"]) == [
        (str(tmp_path / "out" / "f0.exr"), "done"), (str(tmp_path / "out" / "f1.exr"), "done"), ("out/g.exr", "done")]


def test_what_an_earlier_process_with_this_pid_left_is_cleaned_up_and_folded(frames, tmp_path):
    # a container killed and restarted runs as pid 1 again: the files its killed run left carry this process's host
    # and pid. Before, they counted as a live writer's: its temporary stayed for good, and its journal (the frames it
    # finished after its last fold) was taken for this run's and emptied at the first fold without being folded
    import socket

    from sss_jax._io import temporary_prefix

    out = tmp_path / "out"
    out.mkdir()
    left = out / (temporary_prefix(out / "f0.exr") + "abcd1234.tmp.exr")
    left.write_bytes(b"half-written")
    finished = out / "g9.exr"
    finished.write_bytes(b"the killed run's output")
    journal = out / f".{MANIFEST_NAME}.sss_jax-{socket.gethostname()}-{os.getpid()}.journal"
    journal.write_text(json.dumps({"input": "/x/g9.exr", "output": str(finished), "status": "done", "message": "",
                                   "warnings": [], "seconds": 1.0, "run": "killed"}) + "\n")
    for path in (left, journal):  # written before this process started
        os.utime(path, (1e9, 1e9))
    assert process_frames(str(frames / "f0.exr"), "separable", MAT, out_dir=out, taps=9, progress=False,
                          devices=jax.devices()[:1]).ok
    assert not left.exists() and not journal.exists()
    book = json.loads((out / MANIFEST_NAME).read_text())
    assert {pathlib.Path(f["output"]).name: f["status"] for f in book["frames"]} == {"g9.exr": "done",
                                                                                      "f0.exr": "done"}


def test_two_runs_into_one_folder_leave_a_true_manifest(frames, tmp_path):
    # run B starts while run A is at its first frame and runs to the end; A then finds every other frame made by B
    # (not replaced: its writes fail); the manifest must still say every frame is complete, as the disk does
    src = five_frames(frames, tmp_path / "src")
    out = tmp_path / "out"
    inner = []

    def start_b(result):
        if not inner:
            inner.append(process_frames(str(src / "*.exr"), "burley", MAT, out_dir=out, samples=4, progress=False,
                                        devices=jax.devices()[:1]))

    a = process_frames(str(src / "*.exr"), "burley", MAT, out_dir=out, samples=4, progress=False,
                       devices=jax.devices()[:1], resume=False, on_frame_done=start_b)
    b = inner[0]
    assert b.ok and [f.status for f in b.frames] == ["skipped", "done", "done", "done", "done"]
    assert [f.status for f in a.frames] == ["done"] + ["failed"] * 4  # A's own report: it did not replace them
    assert all("created by another process" in f.message for f in a.failed)
    book = json.loads((out / MANIFEST_NAME).read_text())
    assert sorted(pathlib.Path(f["output"]).name for f in book["frames"]) == [f"f{i}.exr" for i in range(5)]
    assert {f["status"] for f in book["frames"]} <= {"done", "skipped"}
    assert all(_io.exr_is_complete(f["output"]) for f in book["frames"])
    assert len(book["runs"]) == 2 and {r["state"] for r in book["runs"]} == {"complete"}


def test_a_frame_failing_after_its_input_was_re_rendered_is_failed_in_the_manifest(frames, tmp_path):
    # a first run completes every frame; f1 is re-rendered and lands cut short, and the next run (resume) fails it.
    # Before, the manifest kept the first run's "done" because its output exists, though that output was made from
    # the earlier input (a review, 2026-12-07); an output made from this very input stays complete (the test above)
    src = tmp_path / "src"
    src.mkdir()
    for i in range(3):
        copy_frame(frames, f"f{i}.exr", src / f"f{i}.exr")
    out = tmp_path / "out"
    run = lambda: process_frames(str(src / "*.exr"), "separable", MAT, out_dir=out, taps=9, progress=False,
                                 devices=jax.devices()[:1])
    assert run().ok
    data = (src / "f1.exr").read_bytes()
    (src / "f1.exr").write_bytes(data[: len(data) // 2])
    again = run()
    assert [f.status for f in again.frames] == ["skipped", "failed", "skipped"]
    book = json.loads((out / MANIFEST_NAME).read_text())
    status = {pathlib.Path(f["output"]).name: (f["status"], f["message"]) for f in book["frames"]}
    assert [status[f"f{i}.exr"][0] for i in range(3)] == ["skipped", "failed", "skipped"]
    assert "f1.exr" in status["f1.exr"][1]
    assert (out / "f1.exr").exists()  # the earlier output stays on the disk: the manifest says it is not this input's


def test_a_killed_runs_journal_is_folded_into_the_manifest_by_the_next_run(frames, tmp_path):
    # entries go to a per-run journal between folds of the manifest: a run killed (SIGKILL) before its fold leaves
    # its journal, and the next run into the folder folds it in (its frames' entries are not lost), then removes it
    import socket
    import subprocess
    import sys

    from sss_jax._batch import _journal_entries

    src = five_frames(frames, tmp_path / "src")
    out = tmp_path / "out"
    out.mkdir()
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # a pid that is no process now
    journal = out / f".{MANIFEST_NAME}.sss_jax-{socket.gethostname()}-{gone.pid}.journal"
    killed = [{"input": str(tmp_path / "elsewhere" / f"k{i}.exr"), "output": str(out / f"k{i}.exr"),
               "status": "failed", "message": f"killed run's frame {i}", "warnings": [], "seconds": 0.1,
               "run": "killed-run"} for i in range(2)]
    journal.write_bytes(b"".join((json.dumps(e) + "\n").encode() for e in killed) + b'{"input": "cut sh')
    assert [e["message"] for e in _journal_entries(journal)] == ["killed run's frame 0", "killed run's frame 1"]
    r = process_frames(str(src / "*.exr"), "burley", MAT, out_dir=out, samples=4, progress=False,
                       devices=jax.devices()[:1])
    assert r.ok
    book = json.loads((out / MANIFEST_NAME).read_text())
    by_output = {pathlib.Path(f["output"]).name: f for f in book["frames"]}
    assert [by_output[f"k{i}.exr"]["message"] for i in range(2)] == ["killed run's frame 0", "killed run's frame 1"]
    assert all(by_output[f"f{i}.exr"]["status"] == "done" for i in range(5))
    assert not journal.exists()
    assert sorted(p.name for p in out.iterdir()) == [f"f{i}.exr" for i in range(5)] + [MANIFEST_NAME]


def test_stale_temporaries_are_removed_and_live_ones_kept(frames, tmp_path):
    import os
    import socket
    import subprocess
    import sys
    import time

    src = five_frames(frames, tmp_path / "src")
    out = tmp_path / "out"
    out.mkdir()
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # a pid that is no process now: a writer killed by SIGKILL
    host = socket.gethostname()
    stale = [out / f".f0.exr.sss_jax-{host}-{gone.pid}.k3j4h5g6.tmp.exr",
             out / f".f1.png.sss_jax-{host}-{gone.pid}.a1b2c3d4.tmp.png",
             out / f".{MANIFEST_NAME}.sss_jax-{host}-{gone.pid}.zz99yy88.tmp.json",
             out / ".f2.exr.q1w2e3r4.tmp.exr"]  # before temporaries named their writer: removed when an hour old
    kept = [out / f".f3.exr.sss_jax-{host}-{os.getpid()}.live1234.tmp.exr",  # a live writer's
            out / f".other.exr.sss_jax-{host}-{gone.pid}.n0tm1n3x.tmp.exr",  # not an output of this run
            out / ".f4.exr.y7u8i9o0.tmp.exr"]  # unnamed and fresh: perhaps a writer of another version, still running
    for p in stale + kept:
        p.write_bytes(b"partial")
    hour_ago = time.time() - 3600
    os.utime(stale[-1], (hour_ago, hour_ago))
    r = process_frames(str(src / "*.exr"), "burley", MAT, out_dir=out, png=True, samples=4, progress=False,
                       devices=jax.devices()[:1])
    assert r.ok
    assert temporaries(out) == sorted(p.name for p in kept)


def test_the_technique_warnings_reach_the_user_once_and_the_manifest_per_frame(frames, tmp_path):
    # 5 taps for kernels up to ~20 px wide: the separable pass's tap cells are too coarse for a hard edge
    src = five_frames(frames, tmp_path / "src")
    with pytest.warns(sj.SamplingWarning) as caught:
        r = process_frames(str(src / "*.exr"), "separable", MAT, out_dir=tmp_path / "out", taps=5, progress=False,
                           devices=jax.devices()[:1])
    assert r.ok
    sampling = [w for w in caught if issubclass(w.category, sj.SamplingWarning)]
    assert len(sampling) == 1 and "5 taps" in str(sampling[0].message)  # once per batch, not once per frame
    book = json.loads((tmp_path / "out" / MANIFEST_NAME).read_text())
    assert all(any("5 taps" in w for w in f["warnings"]) for f in book["frames"])
    # with several devices (vmapped groups) the same check runs on the host before tracing
    with pytest.warns(sj.SamplingWarning, match="5 taps"):
        r4 = process_frames(str(src / "*.exr"), "separable", MAT, out_dir=tmp_path / "out4", taps=5, progress=False)
    assert r4.ok and all(any("5 taps" in w for w in f.warnings) for f in r4.frames)


def test_small_frames_compute_two_at_a_time_in_order_and_a_failed_call_fails_its_frame_alone(frames, tmp_path,
                                                                                           monkeypatch):
    # one device, small frames of one shape: the first runs alone (it compiles), then COMPUTE_THREADS frames' calls
    # run at once in the compute threads; the calls here linger, so overlapping calls show that they do; results,
    # manifest and files keep the frames' order, the pixels are a one-at-a-time run's, and a frame whose call fails
    # (in a compute thread) fails alone, named
    import threading
    import time

    from sss_jax import _batch

    src = five_frames(frames, tmp_path / "src")
    sums = [float(_io.read_frame(src / f"f{i}.exr").irradiance.sum()) for i in range(5)]
    spans, real = [], _batch._run_whole

    def lingering(tech, buffers, material, camera, recorder):
        k = int(np.argmin([abs(float(np.asarray(buffers.irradiance).sum()) - s) for s in sums]))
        t0 = time.monotonic()
        out = real(tech, buffers, material, camera, recorder)
        np.asarray(out[0])
        time.sleep(0.3)
        spans.append((k, threading.current_thread().name, t0, time.monotonic()))
        if k == 3:
            raise ValueError("frame 3's call failed")
        return out

    monkeypatch.setattr(_batch, "_run_whole", lingering)
    r = process_frames(str(src / "*.exr"), "burley", MAT, out_dir=tmp_path / "two", samples=4, progress=False,
                       devices=jax.devices()[:1])
    assert [pathlib.Path(f.input).name for f in r.frames] == [f"f{i}.exr" for i in range(5)]
    assert [f.status for f in r.frames] == ["done", "done", "done", "failed", "done"]
    assert "frame 3's call failed" in r.frames[3].message
    book = json.loads((tmp_path / "two" / MANIFEST_NAME).read_text())
    assert {pathlib.Path(f["input"]).name: f["status"] for f in book["frames"]} == {
        f"f{i}.exr": "failed" if i == 3 else "done" for i in range(5)}
    assert sorted(p.name for p in (tmp_path / "two").iterdir()) == sorted(
        [MANIFEST_NAME] + [f"f{i}.exr" for i in (0, 1, 2, 4)])
    overlap = lambda a, b: a[2] < b[3] and b[2] < a[3]
    first = next(s for s in spans if s[0] == 0)
    assert not any(overlap(first, s) for s in spans if s is not first)  # the compiling frame alone
    assert any(overlap(a, b) and a[1] != b[1] for a in spans for b in spans if a[0] < b[0])
    assert any(name.startswith("sss_jax-compute") for _, name, _, _ in spans)

    monkeypatch.setattr(_batch, "COMPUTE_THREADS", 1)  # one at a time, in the main thread: the same pixels
    spans.clear()
    r1 = process_frames(str(src / "*.exr"), "burley", MAT, out_dir=tmp_path / "one", samples=4, progress=False,
                        devices=jax.devices()[:1])
    assert [f.status for f in r1.frames] == [f.status for f in r.frames]
    assert not any(overlap(a, b) for a in spans for b in spans if a is not b)
    for i in (0, 1, 2, 4):
        np.testing.assert_array_equal(read_rgb(tmp_path / "two" / f"f{i}.exr"), read_rgb(tmp_path / "one" / f"f{i}.exr"))


def test_frames_of_a_sequence_get_their_own_reproducible_rotation(frames, tmp_path):
    from sss_jax._batch import frame_number

    assert [frame_number(p, 9) for p in ("shot.0042.exr", "f7.exr", "beauty.exr")] == [42, 7, 9]
    assert len({frame_seed(0, n) for n in range(1000)}) == 1000 and frame_seed(0, 0) == 0
    src = tmp_path / "src"
    copy_frame(frames, "f0.exr", src / "a.0001.exr")
    copy_frame(frames, "f0.exr", src / "a.0002.exr")  # the same pixels, the next frame
    out = tmp_path / "out"
    r = process_frames(str(src / "*.exr"), "burley", MAT, out_dir=out, samples=4, progress=False,
                       devices=jax.devices()[:1])
    assert r.ok
    one, two = read_rgb(out / "a.0001.exr"), read_rgb(out / "a.0002.exr")
    assert np.max(np.abs(one - two)) > 1e-3  # another rotation: another sampling error
    header = _io.read_header(out / "a.0002.exr")[0]
    assert int(header["sss_jax:seed"]) == frame_seed(0, 2)
    # reproducible: frame 2 alone (another subset of the sequence) gets the same pixels
    alone = process_frames(str(src / "a.0002.exr"), "burley", MAT, out_dir=tmp_path / "alone", samples=4,
                           progress=False, devices=jax.devices()[:1])
    assert alone.ok
    np.testing.assert_array_equal(read_rgb(tmp_path / "alone" / "a.0002.exr"), two)


def test_the_batch_fuzz_of_stop_51(tmp_path, capsys, as_users_run_it):
    # reading options that hold for every frame were checked per frame (each frame failed alone, a manifest
    # written); a list as the channel map failed inside pathlib; a file named with a pattern's characters was
    # "no files match"; "**" matched one level only; a frame without SSS pixels recorded only its clamp
    import warnings as _warnings

    from sss_jax._batch import expand_inputs

    sc = sj.demo_scene(12, 16)
    e, z = np.asarray(sc.buffers.irradiance), np.asarray(sc.buffers.depth)
    chans = {"R": e[..., 0], "G": e[..., 1], "B": e[..., 2], "Z": np.where(np.isfinite(z), z, -1.0)}
    attrs = {"sss_jax:focal_px": float(sc.camera.focal_px), "sss_jax:mm_per_unit": 10.0}
    src = tmp_path / "in"
    (src / "sub").mkdir(parents=True)
    _io.write_exr(src / "shot[v2].exr", chans, attributes=attrs)
    _io.write_exr(src / "sub" / "f1.exr", chans, attributes=attrs)
    assert expand_inputs(str(src / "shot[v2].exr")) == [src / "shot[v2].exr"]
    assert expand_inputs(str(src / "**" / "*.exr")) == [src / "shot[v2].exr", src / "sub" / "f1.exr"]
    mat = sj.BurleyMaterial((0.8, 0.5, 0.4), (3.0, 1.4, 0.8))
    for kwargs, message in ((dict(depth_kind="bogus"), "depth_kind='bogus' is not one of"),
                            (dict(channel_map=["R", "G", "B"]), "channel map: a dict of buffer name"),
                            (dict(channel_map={"irradience": "R"}), "irradience"),
                            (dict(focal_px=float("inf")), r"focal_px must be a positive number \(finite\)"),
                            (dict(out_dir=""), "out_dir is empty")):
        out = tmp_path / "out"
        with pytest.raises((ValueError, TypeError), match=message):
            sj.process_frames(str(src / "sub" / "*.exr"), "burley", mat, **{"out_dir": out, **kwargs},
                              progress=False)
        assert not out.exists()
    # no SSS pixel: what the reader said is the frame's record too
    _io.write_exr(src / "bg.exr", {**chans, "Z": np.full_like(z, -1.0)}, attributes=attrs)
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore")
        r = sj.process_frames(str(src / "bg.exr"), "burley", mat, out_dir=tmp_path / "o2", progress=False)
    assert r.frames[0].status == "done"
    assert any("no pixel to scatter" in w for w in r.frames[0].warnings), r.frames[0].warnings


def test_a_preview_left_from_an_earlier_run_is_said(tmp_path):
    # an output recomputed without png kept the earlier run's preview beside it without a word (other pixels)
    import warnings as _warnings

    sc = sj.demo_scene(12, 16)
    e, z = np.asarray(sc.buffers.irradiance), np.asarray(sc.buffers.depth)
    _io.write_exr(tmp_path / "f1.exr", {"R": e[..., 0], "G": e[..., 1], "B": e[..., 2],
                                        "Z": np.where(np.isfinite(z), z, -1.0)},
                  attributes={"sss_jax:focal_px": float(sc.camera.focal_px), "sss_jax:mm_per_unit": 10.0})
    first = sj.process_frames(str(tmp_path / "f1.exr"), "burley", sj.BurleyMaterial((0.8,) * 3, (1.0,) * 3),
                              out_dir=tmp_path / "out", png=True, progress=False)
    assert first.ok and (tmp_path / "out" / "f1.png").exists()
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore")
        again = sj.process_frames(str(tmp_path / "f1.exr"), "burley", sj.BurleyMaterial((0.5,) * 3, (2.0,) * 3),
                                  out_dir=tmp_path / "out", progress=False)
    assert again.frames[0].status == "done"
    assert any("f1.png: a preview of an earlier output" in w for w in again.frames[0].warnings)


@pytest.mark.parametrize("make", [lambda: sj.HdrpPass(frames=10**6), lambda: sj.EeveeNextPass(frames=10**6)])
def test_a_long_engine_average_is_planned_in_pieces(make):
    # apply --technique eevee-next --frames 1e9 ran as one call: no progress, SIGINT and SIGTERM unheard for as long
    # as it ran (EEVEE Next's cost ignored its frames; neither pass split its frames)
    from sss_jax._batch import TILE_PIXELS, _Cost, _plan_frame

    sc = sj.demo_scene(24, 32)
    plan = _plan_frame(make(), sc.buffers, sj.BurleyMaterial((0.8, 0.5, 0.4), (3.0, 1.4, 0.8)), sc.camera,
                       TILE_PIXELS, _Cost())
    assert plan.pieces is not None and len(plan.pieces) > 10 and plan.layout is None
    assert sum(w for _, w in plan.pieces) == pytest.approx(1.0)


def test_the_work_bound_tiles_a_frame_only_where_the_halos_cost_little(monkeypatch):
    # a frame that fits the memory bound but passes the work bound ran in tiles whatever their halos cost where the
    # technique has no pieces: HDRP over a 1920x1080 frame in 6 tiles of 1080x1212 px, 3.6x the frame's work
    from sss_jax._batch import TILE_PIXELS, _Cost, _plan_frame, _seconds_per_px

    sc = sj.demo_scene(96, 128)
    tech = sj.JimenezPass(taps=11)  # it computes its halo (no keep) and has no pieces
    assert tech.pieces(8) is None
    wide, narrow = sj.BurleyMaterial((0.8, 0.5, 0.4), (3.0,) * 3), sj.BurleyMaterial((0.8, 0.5, 0.4), (0.05,) * 3)
    # the frame passes the work bound: tiles of ~48x48 px
    monkeypatch.setenv("SSS_JAX_CALL_SECONDS", repr(_seconds_per_px(tech) * 48 * 48))
    for material, tiled in ((wide, False), (narrow, True)):
        plan = _plan_frame(tech, sc.buffers, material, sc.camera, TILE_PIXELS, _Cost())
        halo = tech.reach_px(sc.buffers, material, sc.camera)
        assert (plan.layout is not None) == tiled, (halo, plan.layout)
        if tiled:  # the tiles' pixels with their halos at most 1.5x the frame's
            ty, tx = plan.layout
            assert plan.tiles * min(ty + 2 * halo, 96) * min(tx + 2 * halo, 128) <= 1.5 * 96 * 128
    # past the memory bound the frame is tiled whatever the halos cost
    plan = _plan_frame(tech, sc.buffers, wide, sc.camera, 32 * 32, _Cost())
    assert plan.layout is not None


def test_a_technique_that_computes_only_what_a_tile_keeps_is_tiled_by_its_kept_pixels(monkeypatch):
    # HDRP's and EEVEE Next's tiles computed their halos too, and were sized as if they did: a 3840x2160 close-up
    # through HDRP ran in 112 tiles of 745x745 px keeping 345x345 each (135.9 s; the frame whole 17.3 s). They
    # compute only the pixels they keep now (keep=), so the work bound sizes the kept part and the memory bound the
    # tile with its halo
    import sss_jax._batch as B
    from sss_jax._batch import (
        _Cost,
        _plan_frame,
        _seconds_per_px,
        _takes_keep,
        _work_share,
    )

    sc = sj.demo_scene(96, 128)
    material = sj.BurleyMaterial((0.8, 0.5, 0.4), (3.0, 1.4, 0.8))
    # kept parts of at least 128x128 px where the frame has them (smaller calls run slower per pixel)
    big = sj.demo_scene(400, 600)
    hdrp = sj.HdrpPass(quality="low")
    monkeypatch.setenv("SSS_JAX_CALL_SECONDS", repr(_seconds_per_px(hdrp) * _work_share(hdrp, big.buffers) * 32 * 32))
    ty, tx = _plan_frame(sj.HdrpPass(quality="low"), big.buffers, material, big.camera, 1 << 21, _Cost()).layout
    assert 64 <= min(ty, tx) and max(ty, tx) <= 128, (ty, tx)  # (equal tiles: 400 px as 4 of 100)
    monkeypatch.setattr(B, "MIN_KEPT_SIDE", 8)  # the rule below it, on a small frame
    for tech in (sj.HdrpPass(quality="low"), sj.EeveeNextPass(frames=1), sj.Burley(samples=8), sj.Reference()):
        assert _takes_keep(tech)
        halo = tech.reach_px(sc.buffers, material, sc.camera)
        assert (32 + 2 * halo) ** 2 > 2 * 32 * 32, (tech.name, halo)  # tiles with halos would cost 2x and more
        bound = _seconds_per_px(tech) * _work_share(tech, sc.buffers) * 32 * 32
        monkeypatch.setenv("SSS_JAX_CALL_SECONDS", repr(bound))
        # the frame fits the memory bound, and passes the work bound: kept parts of ~32x32 px, whatever the halo
        plan = _plan_frame(tech, sc.buffers, material, sc.camera, 1 << 21, _Cost())
        assert plan.layout is not None, tech.name
        ty, tx = plan.layout
        inner = max(32, halo + 8)  # at least the halo wide (a tile holds at most ~9x what it keeps)
        assert 0.5 * inner * inner <= ty * tx <= inner * inner, (tech.name, halo, plan.layout)
        assert plan.tiles * ty * tx <= 1.5 * 96 * 128 and plan.pieces is None
        # the memory bound sizes the tile with its halo: kept parts as large as fit in it with their halo
        monkeypatch.setenv("SSS_JAX_CALL_SECONDS", "1000")
        narrow = sj.BurleyMaterial((0.8, 0.5, 0.4), (1.0, 0.5, 0.3))
        halo = tech.reach_px(sc.buffers, narrow, sc.camera)
        inner = halo + 20
        side = 2 * halo + inner
        plan = _plan_frame(tech, sc.buffers, narrow, sc.camera, side * side, _Cost())
        ty, tx = plan.layout
        assert max(ty, tx) <= inner and (ty + 2 * halo) * (tx + 2 * halo) <= side * side, (tech.name, plan.layout)
        assert ty * tx >= 0.5 * inner * inner, (tech.name, plan.layout)  # (equal tiles: 96 px as 3 of 32)


def test_a_frame_is_read_and_checked_while_the_device_computes(tmp_path):
    # the reader thread checked a frame's device buffers, which JAX's CPU backend makes readable only once the
    # computations queued before them are done: the next frame waited for the one computing. Checked on the host,
    # put on the device and remembered as checked, the same buffers are ready while the device is busy
    from sss_jax._batch import _Batch, _Job
    from sss_jax._scene import passed

    sc = sj.demo_scene(48, 64)
    b = sc.buffers
    src = tmp_path / "f.exr"
    _io.write_exr(src, {"R": np.asarray(b.irradiance[..., 0]), "G": np.asarray(b.irradiance[..., 1]),
                        "B": np.asarray(b.irradiance[..., 2]), "Z": np.asarray(b.depth),
                        "id": np.asarray(b.material_id).astype(np.float32)},
                  attributes={"sss_jax:focal_px": float(sc.camera.focal_px), "sss_jax:mm_per_unit": 10.0})
    material = sj.BurleyMaterial(np.tile([[0.8, 0.5, 0.4]], (3, 1)), np.tile([[3.0, 1.4, 0.8]], (3, 1)))
    a = jax.numpy.full((768, 768), 1e-3, jax.numpy.float32)
    busy = jax.jit(lambda x: jax.lax.fori_loop(0, 150, lambda i, y: jax.numpy.tanh(y @ x), x))
    busy(a).block_until_ready()  # compiled
    reader = types.SimpleNamespace(material=material)
    # process_frames' defaults
    options = {"channel_map": None, "focal_px": None, "mm_per_unit": None, "depth_kind": "planar"}
    _Batch.decode(reader, _Job(src, tmp_path / "o.exr", 0), options, True)  # warm
    running = busy(a)  # ~0.5-1 s of work, not waited for
    decoded, error, _ = _Batch.decode(reader, _Job(src, tmp_path / "o.exr", 0), options, True)
    assert error is None and not running.is_ready()
    frame, buffers, _ = decoded
    assert passed(buffers, 3)  # the technique's own check finds it done
    running.block_until_ready()
    device = frame.to_buffers()  # the frame's buffers as they were put on the device before
    for mine, theirs in zip(jax.tree.leaves(buffers), jax.tree.leaves(device), strict=True):
        assert isinstance(mine, jax.Array) and mine.dtype == theirs.dtype
        np.testing.assert_array_equal(np.asarray(mine), np.asarray(theirs))


def test_the_plans_share_of_sss_pixels_does_not_wait_behind_the_device():
    # JAX's CPU backend runs one computation after another: the share as a JAX reduction waited, in the batch's plan,
    # for the frame computing before it (2.3 ms a 256x256 frame in a batch of Burley against 0.13 ms alone,
    # 2026-12-07); read from the planes on the host it returns while the device is busy
    from sss_jax._batch import _work_share

    sc = sj.demo_scene(96, 128)
    buffers = jax.block_until_ready(sc.buffers)
    z, ids = np.asarray(buffers.depth), np.asarray(buffers.material_id)
    share = np.count_nonzero(np.isfinite(z) & (z > 0) & (ids > 0)) / z.size
    a = jax.numpy.full((768, 768), 1e-3, jax.numpy.float32)
    busy = jax.jit(lambda x: jax.lax.fori_loop(0, 150, lambda i, y: jax.numpy.tanh(y @ x), x))
    busy(a).block_until_ready()  # compiled
    running = busy(a)  # ~0.5-1 s of work, not waited for
    assert _work_share(sj.Burley(samples=8), buffers) == pytest.approx(share)
    assert not running.is_ready()
    running.block_until_ready()


def test_the_work_of_a_technique_that_computes_only_sss_pixels_follows_their_share():
    # burley, hdrp and eevee-next compute only the SSS pixels (a quarter of the demo frame): costed as if every pixel
    # were computed, a 1920x1080 frame through HDRP (0.9-1.0 s of work) ran in 6 tiles, each compiling its own
    # compacted program (5.6 s); costed by the share, it runs whole
    from sss_jax._batch import (
        MIN_WORK_SHARE,
        TILE_PIXELS,
        _Cost,
        _plan_frame,
        _seconds_per_px,
        _work_share,
    )

    sc = sj.demo_scene(96, 128)
    z, ids = np.asarray(sc.buffers.depth), np.asarray(sc.buffers.material_id)
    share = float(np.mean(np.isfinite(z) & (z > 0) & (ids > 0)))
    assert 0.1 < share < 0.5
    material = sj.BurleyMaterial((0.8, 0.5, 0.4), (3.0, 1.4, 0.8))
    for tech in (sj.Burley(samples=8), sj.HdrpPass(quality="low"), sj.EeveeNextPass(frames=2)):
        assert type(tech).sss_pixels_only and _work_share(tech, sc.buffers) == pytest.approx(share)
        plan = _plan_frame(tech, sc.buffers, material, sc.camera, TILE_PIXELS, _Cost())
        assert plan.share == pytest.approx(share)
        assert plan.estimate_s == pytest.approx(_seconds_per_px(plan.tech) * share * 96 * 128)
        # a frame without SSS pixels is costed at the least share (the set-up runs over every pixel)
        none = sj.Buffers(irradiance=sc.buffers.irradiance, depth=sc.buffers.depth,
                          material_id=jax.numpy.zeros_like(sc.buffers.material_id))
        assert _work_share(tech, none) == MIN_WORK_SHARE
    for tech in (sj.JimenezPass(taps=11), sj.Reference(radius_px=3), sj.Separable(taps=9)):  # every pixel computed
        assert not type(tech).sss_pixels_only and _work_share(tech, sc.buffers) == 1.0


@pytest.mark.parametrize("callback", ["on_frame_done", "on_progress"])
def test_a_callback_that_raises_stops_the_batch_with_its_own_error(frames, tmp_path, callback):
    # on_progress raising a ValueError failed the frame under the input's name and the batch went on; on_frame_done
    # raising one inside the next frame's settle failed that frame instead. One rule now: the caller's error stops
    # the batch and reaches the caller as raised; what was recorded stays on disk and in the manifest.
    # every frame in several calls (tiles for the memory bound): on_progress is called
    more = {"tile_pixels": 24 * 24} if callback == "on_progress" else {}

    class Mine(ValueError):
        pass

    told = []

    def boom(what):
        told.append(what)
        if callback == "on_progress" or len(told) == 2:  # the second frame's: the frames after it compute by then
            raise Mine("the caller's own bug")

    with pytest.raises(Mine, match="the caller's own bug") as caught:
        process_frames(str(frames / "*.exr"), "burley", MAT, out_dir=tmp_path / "run", samples=4,
                       progress=False, devices=jax.devices()[:1], **{callback: boom}, **more)
    if sys.version_info >= (3, 11):  # add_note: the callback named, and how far the batch went
        assert any(f"process_frames' {callback} callback: the batch stopped after" in n
                   for n in caught.value.__notes__), caught.value.__notes__
    book = json.loads((tmp_path / "run" / MANIFEST_NAME).read_text())
    assert book["state"] == "stopped"  # not "interrupted", a signal's (the same word before 2026-12-06)
    assert "failed" not in [f["status"] for f in book["frames"]]  # no frame took the callback's error as its own
    if callback == "on_frame_done":  # the frames it was told of are recorded and written
        assert [f["status"] for f in book["frames"][:2]] == ["done", "done"] and (tmp_path / "run" / "f1.exr").exists()


def test_options_outputs_and_devices_a_batch_cannot_use_are_refused_before_any_frame(frames, tmp_path, as_users_run_it):
    # a named option the technique lacks was dropped without a word (taps for burley), an unknown technique option
    # is the registry's error; both outputs and out_dir wrote the manifest into out_dir, devices=[] ran on the default device, and a manifest
    # path that is a folder was refused after the outputs' folder was made
    src = str(frames / "f0.exr")
    for kwargs, error, message in (
            ({"technique_options": {"taps": 9}}, TypeError, "technique 'burley' has no option.*taps"),
            ({"outputs": [tmp_path / "x.exr"]}, ValueError, "give out_dir or outputs, not both"),
            ({"devices": []}, ValueError, "devices must be jax devices"),
            ({"devices": ["cpu"]}, ValueError, "devices must be jax devices")):
        with pytest.raises(error, match=message):
            process_frames(src, "burley", MAT, out_dir=tmp_path / "out", samples=4, progress=False, **kwargs)
        assert not (tmp_path / "out").exists() and not (tmp_path / "x.exr").exists()
    # a count or STA option the named technique lacks (a script passing every count): said, not used
    with pytest.warns(UserWarning, match="sta_albedo, taps: not an option of 'burley', not used"):
        r = process_frames(src, "burley", MAT, out_dir=tmp_path / "used", samples=4, taps=9,
                           sta_albedo=(0.5, 0.5, 0.5), progress=False)
    assert r.ok and json.loads(_io.read_header(tmp_path / "used" / "f0.exr")[0]["sss_jax:rules"])["samples"] == 4
    (tmp_path / "book").mkdir()
    with pytest.raises(sj.SSSInputError, match="output path is a directory"):
        process_frames(src, "burley", MAT, out_dir=tmp_path / "out", manifest=tmp_path / "book", samples=4,
                       progress=False)
    assert not (tmp_path / "out").exists()


def test_apply_runs_a_technique_at_its_own_default_count(frames, tmp_path):
    # apply filled a count left out with separable's 25 taps for any technique with taps: jimenez ran SSSS_QUALITY 2
    # (25 taps) where the library's and the engine's default is 17. And on several devices (the tests run 4) the
    # batch vmapped the frames, cameras traced: jimenez, which fits a BurleyMaterial's shader parameters on the host
    # at the camera's scene unit, failed every frame; such a technique's frames now run one by one
    from sss_jax.cli import main

    outs = {}
    for label, extra in (("default", []), ("17", ["--taps", "17"]), ("25", ["--taps", "25"])):
        outs[label] = tmp_path / f"{label}.exr"
        assert main(["apply", str(frames / "f0.exr"), "-o", str(outs[label]), "--technique", "jimenez",
                     "--d-mm", "2,1,0.5"]  + extra) == 0
    read = {k: _io.read_channels(v)[0]["R"] for k, v in outs.items()}
    np.testing.assert_array_equal(read["default"], read["17"])
    assert np.abs(read["default"] - read["25"]).max() > 1e-4


def test_png_previews_do_not_replace_someone_elses_png(frames, tmp_path):
    # a foreign EXR at the output was refused, a foreign PNG where its preview goes was replaced without a word
    src = copy_frame(frames, "f0.exr", tmp_path / "in" / "shot.exr")
    out = tmp_path / "out" / "shot.exr"
    out.parent.mkdir()
    theirs = out.with_suffix(".png")
    _io.write_png_preview(theirs, np.full((4, 4, 3), 0.5))
    before = theirs.read_bytes()
    with pytest.raises(_io.SSSInputError, match=r"shot\.png exists and is not the preview of an output made from"):
        process_frames([src], "burley", MAT, outputs=[out], samples=4, png=True, progress=False)
    assert theirs.read_bytes() == before and not out.exists()
    # this batch's own preview is its: beside its EXR, or alone (a run killed between the two writes)
    theirs.unlink()
    assert process_frames([src], "burley", MAT, outputs=[out], samples=4, png=True, progress=False).ok
    assert _io.png_attribute(theirs, "sss_jax:input") == str(src)
    out.unlink()
    assert process_frames([src], "burley", MAT, outputs=[out], samples=4, png=True, progress=False).ok
    # and overwrite=True replaces anyone's
    _io.write_png_preview(theirs, np.full((4, 4, 3), 0.5))
    assert process_frames([src], "burley", MAT, outputs=[out], samples=4, png=True, overwrite=True,
                          progress=False).ok
