"""Batch processing: sharding over devices, resuming after an interruption, per-frame failures, process shares."""

import json
import re

import jax
import numpy as np
import pytest

import sss_jax as sj
from sss_jax import _io
from sss_jax._batch import MANIFEST_NAME, frames_for_process, process_frames

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
    for i in range(5):
        np.testing.assert_array_equal(read_rgb(tmp_path / "o4" / f"f{i}.exr"), read_rgb(o1 / f"f{i}.exr"))
    # and each frame equals the single-frame API
    f = _io.read_frame(frames / "f3.exr")
    single = np.asarray(sj.burley(f.to_buffers(), MAT, sj.Camera(f.focal_px, 10.0), samples=8))
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
    (lambda d: d["burley"].update(d_mm=[-1, 1, 1]), r"invalid preset: d_mm must lie in"),
    (lambda d: d["separable"]["two_gaussian"].update(w=[2, 0, 0]), r"invalid preset: w must lie in"),
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
