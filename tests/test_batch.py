"""Batch processing: sharding over devices, resuming after an interruption, per-frame failures, process shares."""

import jax
import numpy as np
import pytest

import sss_jax as sj
from sss_jax import _io
from sss_jax._batch import frames_for_process, process_frames

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


def test_four_devices_give_the_pixels_of_one(frames, tmp_path):
    assert len(jax.devices()) == 4  # tests/conftest.py splits the host into 4 CPU devices
    r4 = process_frames(str(frames / "*.exr"), "burley", MAT, out_dir=tmp_path / "o4", samples=8, progress=False)
    r1 = process_frames(str(frames / "*.exr"), "burley", MAT, out_dir=tmp_path / "o1", samples=8, progress=False,
                        devices=jax.devices()[:1])
    assert r4.ok and r1.ok and len(r4.frames) == 5
    assert r4.compilations == 1  # one frame shape, one compilation, 5 frames in 2 sharded groups
    for i in range(5):
        np.testing.assert_array_equal(read_rgb(tmp_path / "o4" / f"f{i}.exr"), read_rgb(tmp_path / "o1" / f"f{i}.exr"))
    # and each frame equals the single-frame API
    f = _io.read_frame(frames / "f3.exr")
    single = np.asarray(sj.burley(f.to_buffers(), MAT, sj.Camera(f.focal_px, 10.0), samples=8))
    np.testing.assert_allclose(read_rgb(tmp_path / "o4" / "f3.exr"), single, rtol=1e-6, atol=1e-6)


def test_interrupted_batch_resumes_with_identical_output(frames, tmp_path):
    full = process_frames(str(frames / "*.exr"), "separable", MAT, out_dir=tmp_path / "ref", taps=7, progress=False,
                          devices=jax.devices()[:1])
    assert full.ok
    done = []

    def stop_after_two(result):
        done.append(result)
        if len(done) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        process_frames(str(frames / "*.exr"), "separable", MAT, out_dir=tmp_path / "run", taps=7, progress=False,
                       devices=jax.devices()[:1], on_frame_done=stop_after_two)
    names = sorted(p.name for p in (tmp_path / "run").iterdir())
    assert names == ["f0.exr", "f1.exr"]  # complete frames only: no temp or partial files
    again = process_frames(str(frames / "*.exr"), "separable", MAT, out_dir=tmp_path / "run", taps=7, progress=False,
                           devices=jax.devices()[:1])
    assert [f.status for f in again.frames] == ["skipped", "skipped", "ok", "ok", "ok"]
    for i in range(5):
        np.testing.assert_array_equal(read_rgb(tmp_path / "run" / f"f{i}.exr"), read_rgb(tmp_path / "ref" / f"f{i}.exr"))
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == [f"f{i}.exr" for i in range(5)]


def test_a_bad_frame_is_reported_and_the_others_complete(frames, tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    for i in range(3):
        (src / f"f{i}.exr").write_bytes((frames / f"f{i}.exr").read_bytes())
    (src / "f1.exr").write_bytes(b"\x76\x2f\x31\x01 truncated")
    r = process_frames(str(src / "*.exr"), "burley", MAT, out_dir=tmp_path / "o", samples=4, progress=False)
    assert sorted(f.status for f in r.frames) == ["failed", "ok", "ok"]
    bad = r.failed[0]
    assert bad.input.endswith("f1.exr") and "f1.exr" in bad.message
    assert sorted(p.name for p in (tmp_path / "o").iterdir()) == ["f0.exr", "f2.exr"]


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
