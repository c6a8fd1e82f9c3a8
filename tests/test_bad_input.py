"""Bad input everywhere a user can reach it: each case checks the message, the exit status and that nothing was
left behind."""

import json
import pathlib
import re
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import OpenImageIO as oiio
import pytest

import sss_jax as sj
from sss_jax import _io
from sss_jax.cli import main

# what a user sees when the input is wrong: the library's own messages, without the test run's annotation checker
pytestmark = pytest.mark.usefixtures("as_users_run_it")

MATERIAL = ["--technique", "burley", "--d-mm", "1,1,1", "--focal-px", "100"]


def good_exr(path, h=6, w=7, channels=("R", "G", "B", "Z")):
    data = np.ones((h, w, len(channels)), np.float32)
    spec = oiio.ImageSpec(w, h, len(channels), oiio.FLOAT)
    spec.channelnames = tuple(channels)
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), spec)
    out.write_image(data)
    out.close()
    return path


def run_cli(argv):
    try:
        return main(argv)
    except SystemExit as exc:  # argparse's own errors
        return exc.code


def _prepare(tmp_path, kind):
    """(argv before the options, files to check) for each bad-input case."""
    good = good_exr(tmp_path / "good.exr")
    inp = tmp_path / "in.exr"
    if kind == "empty":
        inp.write_bytes(b"")
    elif kind == "corrupt":
        inp.write_bytes(b"\x76\x2f\x31\x01" + bytes(range(256)) * 4)
    elif kind == "truncated":
        big = good_exr(tmp_path / "big.exr", 64, 64)
        inp.write_bytes(big.read_bytes()[:300])
    elif kind == "missing_channels":
        good_exr(inp, channels=("R", "G", "B"))
    elif kind == "directory":
        inp.mkdir()
    elif kind == "missing_file":
        pass
    else:
        inp = good
    return inp


FILE_CASES = [
    ("empty", "file is empty"),
    ("corrupt", "not a readable image|could not read"),
    ("truncated", "truncated or corrupted|not a readable image|could not read"),
    ("missing_channels", r"missing depth channel\(s\).*channels found: R, G, B"),
    ("directory", "is a directory"),
    ("missing_file", "file not found"),
]


@pytest.mark.parametrize("kind, message", FILE_CASES)
def test_bad_input_files(tmp_path, capsys, kind, message):
    inp = _prepare(tmp_path, kind)
    out = tmp_path / "out" / "o.exr"
    out.parent.mkdir()
    rc = run_cli(["apply", str(inp), "-o", str(out)] + MATERIAL)
    assert rc == 1
    assert re.search(message, capsys.readouterr().err)
    assert list(out.parent.iterdir()) == []


ARG_CASES = [
    (["--technique", "burley", "--focal-px", "100"], "needs the material"),
    (["--technique", "burley", "--d-mm", "1,1,1", "--mfp-mm", "1,1,1"], "either --d-mm or --mfp-mm"),
    (["--technique", "sta", "--focal-px", "100"], "needs --light-dir"),
    (["--technique", "blur", "--d-mm", "1,1,1"], "unknown technique 'blur'; valid techniques: sta, separable"),
    (["--technique", "separable", "--d-mm", "1,1,1", "--focal-px", "100", "--taps", "4"], "--taps must be odd"),
    (MATERIAL + ["--samples", "0"], "--samples must be >= 1"),
    (["--technique", "burley", "--d-mm=-1,1,1"], r"d_mm must be finite and >= 0"),
    (["--technique", "burley", "--d-mm", "nan,1,1"], r"d_mm must be finite and >= 0, got \[nan"),
    (["--technique", "burley", "--d-mm", "1,1,1", "--albedo", "1.5,0.5,0.5"], r"albedo must be >= 0 and <= 1"),
    (["--technique", "burley", "--d-mm", "1,2"], "expected three comma-separated numbers"),
    (MATERIAL + ["--focal-px=-3"], "--focal-px must be a finite positive number"),
    (MATERIAL + ["--mm-per-unit", "0"], "--mm-per-unit must be a finite positive number"),
    (["--technique", "burley", "--mfp-mm=-2,1,1"], r"mfp_mm must be >= 0"),
    (["--technique", "sta", "--light-dir", "0,0,0"], "light direction must be a finite non-zero vector"),
    (["--technique", "sta", "--light-dir", "0,0,1", "--sta-thickness-mm", "0,1,1"], r"thickness_mm must be > 0"),
    # a leading minus as its own word (issue #27/#30): the value reaches the command's own check, not argparse's
    # "expected one argument"
    (["--technique", "burley", "--d-mm", "-1,1,1"], r"d_mm must be finite and >= 0"),
    (["--technique", "burley", "--mfp-mm", "-2,1,1"], r"mfp_mm must be >= 0"),
    (MATERIAL + ["--focal-px", "-3"], "--focal-px must be a finite positive number"),
    (MATERIAL + ["--mm-per-unit", "-1e-3"], "--mm-per-unit must be a finite positive number"),
    (MATERIAL + ["--focal-px", "-inf"], "--focal-px must be a finite positive number"),
    (["--technique", "sta", "--light-dir", "0,0,1", "--sta-power", "-1"], r"power must be finite and >= 0"),
]


@pytest.mark.parametrize("argv, message", ARG_CASES)
def test_bad_arguments(tmp_path, capsys, argv, message):
    inp = good_exr(tmp_path / "good.exr")
    out = tmp_path / "out" / "o.exr"
    out.parent.mkdir()
    assert run_cli(["apply", str(inp), "-o", str(out)] + argv) == 2
    assert re.search(message, capsys.readouterr().err)
    assert list(out.parent.iterdir()) == []


def test_negative_light_direction_is_a_value(tmp_path, capsys):
    """``--light-dir -0.25,0.3,0.9`` (issue #27): argparse read the minus as a flag ("expected one argument")."""
    inp = good_exr(tmp_path / "good.exr")
    out = tmp_path / "o.exr"
    rc = run_cli(["apply", str(inp), "-o", str(out), "--technique", "sta", "--light-dir", "-0.25,0.3,0.9",
                  "--focal-px", "100", "--thickness", "0.001"])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "expected one argument" not in err and out.exists()


def test_a_word_that_is_not_a_number_is_still_a_flag(capsys):
    # only numbers are taken for values: a misspelt flag after a flag that wants a value is still argparse's error
    assert run_cli(["apply", "x.exr", "-o", "y.exr", "--technique", "burley", "--d-mm", "--albedo", "1,1,1"]) == 2
    assert "expected one argument" in capsys.readouterr().err


def test_demo_out_onto_an_existing_file(tmp_path, capsys):
    """Issue #30: `demo --out README.md` said "[Errno 17] File exists"."""
    target = tmp_path / "README.md"
    target.write_text("mine")
    assert run_cli(["demo", "--out", str(target), "--size", "8x8"]) == 2
    err = capsys.readouterr().err
    assert f"--out {target} is an existing file, not a folder" in err and "Errno" not in err
    assert target.read_text() == "mine"


def test_demo_out_into_a_folder_of_the_users_own_files(tmp_path, capsys):
    """Issue #30: a folder holding the user's own reference.exr and summary.json was silently overwritten."""
    folder = tmp_path / "mine"
    folder.mkdir()
    good_exr(folder / "reference.exr")
    (folder / "summary.json").write_text('{"my": "notes"}')
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert run_cli(["demo", "--out", str(folder), "--size", "8x8"]) == 2
    err = capsys.readouterr().err
    assert "holds files a demo did not make (reference.exr, summary.json)" in err and "--overwrite" in err
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before


def test_demo_out_into_its_own_earlier_output_or_with_overwrite_is_allowed(tmp_path):
    from sss_jax.cli._demo import _check_out

    folder = tmp_path / "demo"
    folder.mkdir()
    good_exr(folder / "reference.exr")
    (folder / "summary.json").write_text(json.dumps({"made_by": "sss-jax demo", "width": 8, "height": 8, "rows": []}))
    _check_out(folder, overwrite=False)  # a demo's folder: no error
    (folder / "summary.json").write_text('{"my": "notes"}')
    with pytest.raises(ValueError, match="holds files a demo did not make"):
        _check_out(folder, overwrite=False)
    _check_out(folder, overwrite=True)
    (folder / "notes.txt").write_text("")  # files the demo never writes do not count
    (folder / "summary.json").unlink()
    (folder / "reference.exr").unlink()
    _check_out(folder, overwrite=False)


def test_missing_focal_length(tmp_path, capsys):
    inp = good_exr(tmp_path / "good.exr")
    out = tmp_path / "o.exr"
    assert run_cli(["apply", str(inp), "-o", str(out), "--technique", "burley", "--d-mm", "1,1,1"]) == 1
    assert "no focal length" in capsys.readouterr().err and not out.exists()


def test_output_directory_that_cannot_exist(tmp_path, capsys):
    inp = good_exr(tmp_path / "good.exr")
    blocker = tmp_path / "file"
    blocker.write_text("a file, not a directory")
    assert run_cli(["apply", str(inp), "--out-dir", str(blocker / "sub")] + MATERIAL) == 2
    assert "file" in capsys.readouterr().err
    assert not (blocker / "sub").exists()


def test_output_into_missing_directory(tmp_path, capsys):
    inp = good_exr(tmp_path / "good.exr")
    out = tmp_path / "nowhere" / "o.exr"
    assert run_cli(["apply", str(inp), "-o", str(out)] + MATERIAL) == 2  # refused before the frame runs
    assert "output directory does not exist" in capsys.readouterr().err
    assert not out.parent.exists()


def test_invalid_channel_maps(tmp_path, capsys):
    inp = good_exr(tmp_path / "good.exr")
    for text, message in [("{not json", "invalid channel map"), ('{"colour": "R"}', "unknown buffer 'colour'"),
                          ('{"depth": ["Z", "Z"]}', r"'depth' needs 1 channel")]:
        cmap = tmp_path / "map.json"
        cmap.write_text(text)
        out = tmp_path / "o.exr"
        # a bad map is the whole batch's input: refused before any frame, status 2 (it failed each frame: 1)
        assert run_cli(["apply", str(inp), "-o", str(out), "--channel-map", str(cmap)] + MATERIAL) == 2
        assert re.search(message, capsys.readouterr().err)
        assert not out.exists()


def test_glob_matching_nothing_and_too_many_for_o(tmp_path, capsys):
    assert run_cli(["apply", str(tmp_path / "none*.exr"), "--out-dir", str(tmp_path / "o")] + MATERIAL) == 2
    assert "no files match" in capsys.readouterr().err
    a, b = good_exr(tmp_path / "a.exr"), good_exr(tmp_path / "b.exr")
    assert run_cli(["apply", str(a), str(b), "-o", str(tmp_path / "x.exr")] + MATERIAL) == 2
    assert "-o takes one input" in capsys.readouterr().err
    assert not (tmp_path / "x.exr").exists()


@pytest.mark.parametrize("make, message", [
    (lambda: sj.Buffers(irradiance=jnp.ones((4, 4, 4)), depth=jnp.ones((4, 4))), r"irradiance must have shape \(H, W, 3\)"),
    (lambda: sj.Buffers(irradiance=jnp.ones((4, 4, 3)), depth=jnp.ones((5, 4))), r"depth shape \(5, 4\) does not match"),
    (lambda: sj.Buffers(irradiance=jnp.ones((4, 4, 3), jnp.int32), depth=jnp.ones((4, 4))), "must be a floating-point"),
    (lambda: sj.Buffers(irradiance=jnp.ones((4, 4, 3)), depth=jnp.ones((4, 4)), material_id=jnp.ones((4, 4))),
     "material_id must be an integer"),
    (lambda: sj.validate_buffers(sj.Buffers(irradiance=jnp.full((2, 2, 3), jnp.nan), depth=jnp.ones((2, 2)))),
     "irradiance has 12 non-finite values"),
    (lambda: sj.validate_buffers(sj.Buffers(irradiance=-jnp.ones((2, 2, 3)), depth=jnp.ones((2, 2)))),
     "irradiance has 12 negative values"),
    (lambda: sj.BurleyMaterial([0.5, 0.5], [1, 1, 1]), r"albedo must have 3 values"),
    (lambda: sj.TwoGaussianMaterial([1, 1, 1], [1.2, 0, 0], [1, 1, 1], [2, 2, 2]), r"w must be >= 0 and <= 1"),
    (lambda: sj.burley(sj.Buffers(irradiance=jnp.ones((4, 4, 3)), depth=jnp.ones((4, 4))),
                       sj.TwoGaussianMaterial([1, 1, 1], [1, 1, 1], [1, 1, 1], [1, 1, 1]), sj.Camera(10.0)),
     "burley needs a BurleyMaterial"),
    (lambda: sj.Camera(-1.0), "focal_px must be a finite positive number"),
    (lambda: sj.translucency(sj.Buffers(irradiance=jnp.ones((4, 4, 3)), depth=jnp.ones((4, 4))), sj.STAParams(),
                             sj.Camera(10.0), sj.DirectionalLight((0.0, 0.0, 1.0)), albedo=(40.0, 0.5, 0.5)),
     r"albedo must be >= 0 and <= 1, got \[40.0, 0.5, 0.5\]"),
    (lambda: sj.translucency(sj.Buffers(irradiance=jnp.ones((4, 4, 3)), depth=jnp.ones((4, 4))), sj.STAParams(),
                             sj.Camera(10.0), sj.DirectionalLight((0.0, 0.0, 1.0)), thickness=-2.0),
     "thickness must be >= 0"),
    (lambda: sj.get_technique("blur"), "valid techniques: sta, separable, burley, reference"),
])
def test_python_api_bad_input(make, message):
    with pytest.raises((ValueError, TypeError), match=message):
        make()


# ------------------------------------------------------------------------------------------------------------------
# buffers of mismatched resolution and invalid values inside an EXR, read through the command line
# ------------------------------------------------------------------------------------------------------------------


def two_part_exr(path, first=(6, 7), second=(2, 3)):
    """A multi-part EXR whose second part (depth) has another resolution than the first (colour)."""
    specs = []
    for (h, w), names, part in ((first, ("R", "G", "B"), "rgb"), (second, ("Z",), "depth")):
        spec = oiio.ImageSpec(w, h, len(names), oiio.FLOAT)
        spec.channelnames = names
        spec.attribute("oiio:subimagename", part)
        # OpenEXR requires one display window for all parts; the data windows are what differ
        spec.full_width, spec.full_height = first[1], first[0]
        specs.append(spec)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), specs)
    out.write_image(np.ones(first + (3,), np.float32))
    assert out.open(str(path), specs[1], "AppendSubimage")
    out.write_image(np.ones(second + (1,), np.float32))
    out.close()
    return path


def exr_with(path, **overrides):
    """A 6x7 EXR with R, G, B, Z (and id) where ``overrides`` replaces whole channels."""
    h, w = 6, 7
    ch = {"R": np.ones((h, w)), "G": np.ones((h, w)), "B": np.ones((h, w)), "Z": np.full((h, w), 10.0),
          "id": np.ones((h, w))}
    ch.update(overrides)
    _io.write_exr(path, {k: np.asarray(v, np.float32) for k, v in ch.items()})
    return path


def _nan_r():
    r = np.ones((6, 7))
    r[2, 3] = np.nan
    return r


@pytest.mark.parametrize("make, message", [
    (lambda p: two_part_exr(p), r"subimage 1 is 3x2 at \(0, 0\), the first is 7x6 at \(0, 0\)"),
    (lambda p: exr_with(p, R=_nan_r()), r"irradiance has 1 non-finite values"),
    (lambda p: exr_with(p, id=-np.ones((6, 7))), r"id channel has negative ids \(min -1\)"),
    (lambda p: exr_with(p, id=np.full((6, 7), np.inf)), r"id channel has non-finite values"),
])
def test_bad_buffers_in_a_file(tmp_path, capsys, make, message):
    inp = make(tmp_path / "in.exr")
    out = tmp_path / "out" / "o.exr"
    out.parent.mkdir()
    assert run_cli(["apply", str(inp), "-o", str(out)] + MATERIAL) == 1
    err = capsys.readouterr().err
    assert "in.exr" in err and re.search(message, err)  # names the file and what is wrong with it
    assert list(out.parent.iterdir()) == []


def test_depth_file_of_another_resolution(tmp_path):
    colour = good_exr(tmp_path / "c.exr", 6, 7, channels=("R", "G", "B"))
    depth = good_exr(tmp_path / "z.exr", 5, 7, channels=("Z",))
    with pytest.raises(_io.SSSInputError, match=r"z.exr: depth is 7x5 but .*c.exr is 7x6"):
        _io.read_frame(colour, depth_path=depth)


# ------------------------------------------------------------------------------------------------------------------
# preset files that are not valid (cases beyond tests/test_batch.py's missing field / bad range / broken JSON)
# ------------------------------------------------------------------------------------------------------------------

GOOD_PRESET = {"name": "p", "albedo": [0.8, 0.6, 0.5], "burley": {"d_mm": [3.0, 1.4, 0.8]}}


@pytest.mark.parametrize("content, technique, message", [
    ("[1, 2, 3]", "burley", "a preset must be a JSON object"),
    ("", "burley", "preset is not valid JSON"),
    ('{"albedo": [0.8, 0.6, 0.5], "burley": {"d_mm": [NaN, 1, 1]}}', "burley", r"invalid preset: d_mm must be finite and >= 0, got \[nan"),
    ('{"albedo": [0.8, "x", 0.5], "burley": {"d_mm": [1, 1, 1]}}', "burley", "albedo must be a list of 3 numbers"),
    (json.dumps(dict(GOOD_PRESET, sta=3)), "burley", "sta must be an object of STA parameters"),
    (json.dumps(dict(GOOD_PRESET, sta={"power": -1.0})), "burley", r"invalid preset: power must be finite and >= 0"),
    # a transmittance table of no values or of text: "invalid preset: tuple index out of range", "could not convert
    # string to float", naming no field (found by a review, 2026-12-07)
    *[(json.dumps(dict(GOOD_PRESET, transmittance={"thickness_mm": bad, "T": [[0.5]] * 3,
                                                   "resolved": [[True]] * 3})), "burley", message)
      for bad, message in (([], (r"transmittance \(thickness_mm, T and resolved: a list per channel\) is not a "
                                 r"table of numbers \(IndexError")),
                           ([["x"]] * 3, "transmittance: could not convert string to float: 'x'"))],
])
def test_invalid_preset_files(tmp_path, capsys, content, technique, message):
    preset = tmp_path / "bad.json"
    preset.write_text(content)
    inp = good_exr(tmp_path / "good.exr")
    out = tmp_path / "out" / "o.exr"
    out.parent.mkdir()
    rc = run_cli(["apply", str(inp), "-o", str(out), "--technique", technique, "--preset", str(preset),
                  "--focal-px", "100"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "bad.json" in err and re.search(message, err)
    assert list(out.parent.iterdir()) == []


def test_preset_without_sta_parameters_for_sta(tmp_path):
    from sss_jax._presets import load_preset, material_for

    preset = tmp_path / "nosta.json"
    preset.write_text(json.dumps(GOOD_PRESET))
    with pytest.raises(_io.SSSInputError, match="nosta.json: preset has no sta parameters"):
        material_for("sta", load_preset(preset))


# ------------------------------------------------------------------------------------------------------------------
# in a batch, a bad frame fails alone: the other frames still complete, and nothing partial is left
# ------------------------------------------------------------------------------------------------------------------


def test_batch_bad_frames_fail_alone(tmp_path):
    from sss_jax._batch import MANIFEST_NAME, process_frames

    src = tmp_path / "src"
    src.mkdir()
    exr_with(src / "a_good.exr")
    exr_with(src / "b_nan.exr", R=_nan_r())
    good_exr(src / "c_nodepth.exr", channels=("R", "G", "B"))
    (src / "d_empty.exr").write_bytes(b"")
    two_part_exr(src / "e_mismatch.exr")
    exr_with(src / "f_good.exr", G=np.full((6, 7), 0.5))
    out = tmp_path / "out"
    mat = sj.BurleyMaterial([0.8, 0.6, 0.5], [1.0, 1.0, 1.0])
    r = process_frames(str(src / "*.exr"), "burley", mat, out_dir=out, samples=4, focal_px=100.0, progress=False,
                       resume=False)
    status = {pathlib.Path(f.input).name: (f.status, f.message) for f in r.frames}
    assert status["a_good.exr"][0] == "done" and status["f_good.exr"][0] == "done"
    expected = {"b_nan.exr": "irradiance has 1 non-finite values", "c_nodepth.exr": r"missing depth channel",
                "d_empty.exr": "file is empty", "e_mismatch.exr": "subimage 1 is 3x2"}
    for name, message in expected.items():
        st, msg = status[name]
        assert st == "failed" and re.search(message, msg, re.IGNORECASE), (name, msg)
    # only the finished frames are there: no temporary or partial files; the manifest names every bad frame
    assert sorted(p.name for p in out.iterdir()) == ["a_good.exr", "f_good.exr", MANIFEST_NAME]
    book = json.loads((out / MANIFEST_NAME).read_text())
    failed = {pathlib.Path(f["input"]).name: f["message"] for f in book["frames"] if f["status"] == "failed"}
    assert sorted(failed) == sorted(expected) and all(n in failed[n] for n in failed)


def test_an_output_path_taken_by_a_directory_stops_the_batch_before_any_frame(tmp_path, capsys):
    # every output path is checked before the work starts: no frame is computed only to fail at its write
    src = tmp_path / "src"
    src.mkdir()
    exr_with(src / "a.exr")
    exr_with(src / "b.exr")
    out = tmp_path / "out"
    (out / "b.exr").mkdir(parents=True)
    assert run_cli(["apply", str(src / "*.exr"), "--out-dir", str(out)] + MATERIAL) == 2
    assert "b.exr: output path is a directory" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["b.exr"] and list((out / "b.exr").iterdir()) == []


def test_montecarlo_json_into_a_folder_that_takes_no_file_fails_before_simulating(tmp_path, capsys, monkeypatch):
    import os
    import tempfile

    import sss_jax._montecarlo as mc

    if os.geteuid() != 0:
        folder = tmp_path / "ro"
        folder.mkdir()
        folder.chmod(0o555)
    else:  # root ignores permission bits; sysfs refuses new files to everyone
        folder = pathlib.Path("/sys/kernel")
        try:
            tempfile.TemporaryFile(dir=folder).close()
            pytest.skip("no folder here refuses new files to root")
        except OSError:
            pass
    ran = []
    monkeypatch.setattr(mc, "simulate", lambda *a, **k: ran.append(1))
    rc = run_cli(["montecarlo", "--albedo", "0.9", "--photons", "1000", "--json", str(folder / "mc.json")])
    assert rc == 2 and ran == []  # refused before the simulation, not a traceback after it
    assert "not writable" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------------------------
# the Python API: more shapes, options and values
# ------------------------------------------------------------------------------------------------------------------

B44 = lambda: sj.Buffers(irradiance=jnp.ones((4, 4, 3)), depth=jnp.full((4, 4), 10.0))
CAM = sj.Camera(100.0)


@pytest.mark.parametrize("make, error, message", [
    (lambda: sj.Buffers(irradiance=jnp.ones((4, 4, 3)), depth=jnp.ones((4, 4)), albedo=jnp.ones((4, 5, 3))),
     ValueError, r"albedo shape \(4, 5, 3\) does not match irradiance \(4, 4, 3\)"),
    (lambda: sj.Buffers(irradiance=jnp.ones((4, 4, 3)), depth=jnp.ones((4, 4)), thickness=jnp.ones((4,))),
     ValueError, r"thickness shape \(4,\) does not match"),
    (lambda: sj.validate_buffers(sj.Buffers(irradiance=jnp.ones((2, 2, 3)), depth=jnp.ones((2, 2)),
                                            material_id=jnp.full((2, 2), 3)), materials=2),
     ValueError, "material_id uses id 3 but only 2 materials were given"),
    (lambda: sj.validate_buffers(sj.Buffers(irradiance=jnp.ones((2, 2, 3)), depth=jnp.ones((2, 2)),
                                            thickness=jnp.full((2, 2), jnp.nan))),
     ValueError, "thickness buffer has 4 NaN values, the first at row 0, column 0; thickness must not be NaN"),
    (lambda: sj.separable(B44(), sj.BurleyMaterial([1, 1, 1], [1, 1, 1]), CAM, taps=4),
     ValueError, "taps must be an odd positive integer"),
    (lambda: sj.burley(B44(), sj.BurleyMaterial([1, 1, 1], [1, 1, 1]), CAM, interpolation="cubic"),
     ValueError, r"interpolation='cubic' is not one of"),
    (lambda: sj.burley(B44(), sj.BurleyMaterial([1, 1, 1], [1, 1, 1]), CAM, albedo_mode="pre"),
     ValueError, r"albedo_mode='pre' is not one of"),
    (lambda: sj.STAParams(power=float("nan")), ValueError, r"power must be finite and >= 0, got nan"),
    (lambda: sj.DirectionalLight([0.0, 0.0]), ValueError, r"light direction must have shape \(3,\)"),
    (lambda: sj.BurleyMaterial([[0.5] * 3] * 2, [[1.0] * 3] * 3), ValueError, "same number of materials"),
    (lambda: sj.two_gaussian_kernel(jnp.ones(3), jnp.ones(2), jnp.ones(3)), ValueError, "must all have shape"),
    (lambda: sj.spiral_samples(0), ValueError, "samples must be a positive integer"),
    (lambda: sj.reference(B44(), sj.BurleyMaterial([1, 1, 1], [1, 1, 1]), CAM, radius_px=-1),
     ValueError, "radius_px must be a non-negative integer"),
])
def test_more_python_api_bad_input(make, error, message):
    with pytest.raises(error, match=message):
        make()


# every technique, with options small enough for a test and a material it takes (two rows where it takes several:
# the id check)
TWO_BURLEY = sj.BurleyMaterial([[1.0, 1.0, 1.0], [0.5, 0.5, 0.5]], [[3.0, 2.0, 1.0], [1.0, 1.0, 1.0]])
ONE_BURLEY = sj.BurleyMaterial([1.0, 1.0, 1.0], [3.0, 2.0, 1.0])
FRONT_DOOR = {
    "burley": (lambda: sj.technique("burley", samples=4), TWO_BURLEY),
    "separable": (lambda: sj.technique("separable", taps=5), TWO_BURLEY),
    "reference": (lambda: sj.technique("reference", radius_px=2, near_subsamples=1), TWO_BURLEY),
    "sta": (lambda: sj.technique("sta", light=sj.DirectionalLight([0.0, 0.0, 1.0]), model="thin"), TWO_BURLEY),
    "hdrp": (lambda: sj.technique("hdrp", quality="low"), TWO_BURLEY),
    "eevee-next": (lambda: sj.technique("eevee-next", frames=1), TWO_BURLEY),
    "jimenez": (lambda: sj.technique("jimenez", taps=11), ONE_BURLEY),  # the shader has one kernel
}


def buffers_with(**changes):
    """An 8x6 frame of surface with two materials (ids 1 and 2), one buffer changed at row 2, column 1."""
    e, a = np.ones((8, 6, 3), np.float32), np.full((8, 6, 3), 0.5, np.float32)
    ids = np.ones((8, 6), np.int32)
    ids[:, 3:] = 2
    fields = {"irradiance": e, "albedo": a, "material_id": ids}
    for name, value in changes.items():
        fields[name][2, 1] = value
    return sj.Buffers(irradiance=jnp.asarray(fields["irradiance"]), depth=jnp.full((8, 6), 10.0),
                      albedo=jnp.asarray(fields["albedo"]), material_id=jnp.asarray(fields["material_id"]))


def test_frame_buffers_the_test_builds_are_valid_for_every_technique():
    # the frames below differ from this one in one value: each technique takes this one
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the small counts' sampling warnings
        for name, (make, material) in FRONT_DOOR.items():
            assert np.all(np.isfinite(np.asarray(make()(buffers_with(), material, CAM)))), name


@pytest.mark.parametrize("name", list(FRONT_DOOR))
@pytest.mark.parametrize("change, message", [
    ({"irradiance": np.nan}, r"irradiance has 3 non-finite values \(NaN or inf\), the first at row 2, column 1"),
    ({"irradiance": np.inf}, r"irradiance has 3 non-finite values \(NaN or inf\), the first at row 2, column 1"),
    ({"albedo": np.nan}, r"albedo buffer has 3 non-finite values \(NaN or inf\), the first at row 2, column 1"),
    ({"material_id": 3}, (r"material_id uses id 3 but only 2 materials were given \(ids 1..2\): 1 pixel above, "
                          r"the first at row 2, column 1")),  # one material: every id > 0 takes it, no error
    ({"material_id": -1}, r"material_id has 1 negative id \(min -1\), the first at row 2, column 1"),
])
def test_every_technique_refuses_bad_buffer_values_naming_the_buffer_and_the_pixel(name, change, message):
    # before: a NaN irradiance pixel turned every pixel within the kernel's reach NaN (59 pixels of a 96x64 demo
    # frame with burley, 630 with separable), an id past the table took the last material's parameters, silently
    make, material = FRONT_DOOR[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if change.get("material_id", 0) > material.count == 1:
            make()(buffers_with(**change), material, CAM)  # one material: every id > 0 takes it
            return
        caller = {"sta": "translucency"}.get(name, name)  # the function the object calls names itself
        with pytest.raises(ValueError, match=f"^{re.escape(caller)}: {message}"):
            make()(buffers_with(**change), material, CAM)


@pytest.mark.parametrize("name", list(FRONT_DOOR))
def test_a_technique_takes_signed_irradiance_and_clips_the_albedo_as_documented(name):
    # the physical rules (irradiance >= 0, albedo in [0, 1]) are the files' (validate_buffers' default, the batch's and
    # the CLI's); a technique is linear in the irradiance and clips the albedo, so neither is an error there
    make, material = FRONT_DOOR[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for change in ({"irradiance": -0.5}, {"albedo": 2.0}):
            assert np.all(np.isfinite(np.asarray(make()(buffers_with(**change), material, CAM)))), (name, change)
    with pytest.raises(ValueError, match="irradiance has 3 negative values"):
        sj.validate_buffers(buffers_with(irradiance=-0.5))
    with pytest.raises(ValueError, match=r"albedo buffer has 3 values outside \[0, 1\]"):
        sj.validate_buffers(buffers_with(albedo=2.0))


def test_buffer_values_are_not_read_back_under_jit():
    # traced buffers cannot be read: the pass runs (validate_buffers is the check to call there), no host error
    import equinox as eqx

    run = eqx.filter_jit(lambda b: sj.burley(b, TWO_BURLEY, CAM, samples=4))
    out = np.asarray(run(buffers_with(irradiance=np.nan)))
    assert np.isnan(out[2, 1]).any()
    with pytest.raises(ValueError, match="irradiance has 3 non-finite values"):
        sj.validate_buffers(buffers_with(irradiance=np.nan))


def test_validate_buffers_names_the_frame_of_a_batch():
    b = buffers_with()
    e = np.ones((3, 8, 6, 3), np.float32)
    e[1, 4, 5, 2] = np.nan
    batch = sj.Buffers(irradiance=jnp.asarray(e), depth=jnp.full((3, 8, 6), 10.0))
    with pytest.raises(ValueError, match=r"the first at row 4, column 5 of frame \(1,\)"):
        sj.validate_buffers(batch)
    sj.validate_buffers(b, materials=2)  # the valid frame passes


def test_buffers_that_passed_are_not_read_again_unless_they_can_change():
    # JAX arrays cannot change: a frame that passed is remembered (the batch checks it, then its technique does);
    # NumPy arrays can be written in place, so they are read on every call
    e = np.ones((4, 4, 3), np.float32)
    held = sj.Buffers(irradiance=e, depth=np.full((4, 4), 10.0, np.float32))
    sj.validate_buffers(held)
    e[1, 2, 0] = np.nan
    with pytest.raises(ValueError, match="irradiance has 1 non-finite value .* row 1, column 2"):
        sj.validate_buffers(held)
    with pytest.raises(ValueError, match="^burley: irradiance has 1 non-finite value"):
        sj.burley(held, ONE_BURLEY, CAM, samples=4)
    frame = buffers_with(material_id=3)
    sj.validate_buffers(frame, materials=3)
    with pytest.raises(ValueError, match="material_id uses id 3 but only 2 materials"):  # another table: read again
        sj.validate_buffers(frame, materials=2)


def test_nan_parameter_inside_jit_is_an_error_not_a_nan_image():
    # under jit the constructors cannot see values: the techniques' eqx.error_if checks must trip on NaN
    import equinox as eqx

    b = B44()

    @eqx.filter_jit  # under plain jax.jit the same check raises too, with a less readable message
    def run(d):
        return sj.burley(b, sj.BurleyMaterial(jnp.ones(3), d), CAM, samples=4)

    assert np.all(np.isfinite(np.asarray(run(jnp.ones(3)))))
    with pytest.raises(eqx.EquinoxRuntimeError, match="d_mm must be finite and >= 0"):
        run(jnp.asarray([1.0, jnp.nan, 1.0])).block_until_ready()


MITSUBA = pathlib.Path(__file__).parent / "data" / "mitsuba"


@pytest.mark.parametrize("argv", [
    ["transmit", "--preset", "skin1", "--thickness-mm", "1"],
    ["advise", "--material", "skin1", "--max-delta-e", "1"],
    ["stability", "--quick"],
    ["fit", "--render", str(MITSUBA / "skin_closeup_buffers.exr"), "--truth", str(MITSUBA / "skin_closeup_truth.exr"),
     "--technique", "burley", "--preset", "skin1", "--max-steps", "1"],
    # convert checked only the folder: a folder as --json ended in IsADirectoryError's traceback
    ["convert", "--from", "sss_jax", "--to", "blender", "--albedo", "0.8,0.6,0.5", "--d-mm", "1,1,1"],
    # bench ran its whole benchmark first, then IsADirectoryError's traceback lost the results
    ["bench", "--quick", "--technique", "sta"],
])
@pytest.mark.parametrize("where", ["a folder", "under a file"])
def test_a_json_output_that_cannot_be_a_file_is_refused_before_the_work(tmp_path, capsys, argv, where):
    # before, these commands checked only that the folder existed: a folder given as --json, or a path under a
    # regular file, ended in a traceback after the work (stability: after its whole sweep, minutes)
    blocker = tmp_path / "file"
    blocker.write_text("a file")
    target = tmp_path if where == "a folder" else blocker / "out.json"
    assert main([*argv, "--json", str(target)]) == 2
    err = capsys.readouterr().err
    assert ("output path is a directory" in err if where == "a folder" else "file" in err) and "Traceback" not in err


@pytest.mark.parametrize("argv, message", [
    # flags of the other mode of `fit` did nothing: a preset fit with --json/--preset wrote neither and used none;
    # a render match with --seed/--solver/--photons/--out ran optimistix, recorded no seed and wrote nothing there
    (["fit", "--list", "--json", "x.json", "--max-steps", "3", "--preset", "skin", "--fit-albedo"],
     "--preset, --fit-albedo, --max-steps, --json: for matching a render"),
    (["fit", "--material", "skin", "--light-dir", "0,0,1", "--sta-power", "2", "--technique", "burley"],
     "--technique, --light-dir, --sta-power: for matching a render"),
    (["fit", "--render", str(MITSUBA / "skin_closeup_buffers.exr"), "--truth", str(MITSUBA / "skin_closeup_truth.exr"),
      "--technique", "burley", "--preset", "skin1", "--seed", "5", "--solver", "jaxopt", "--photons", "3"],
     "--photons, --seed, --solver: for making presets"),
    # the STA match fits the STA model's parameters; the thin and slab models have none (before: "technique 'sta'
    # starts from STAParams", which did not say why)
    (["fit", "--render", str(MITSUBA / "skin_backlit_buffers.exr"), "--truth", str(MITSUBA / "skin_backlit_truth.exr"),
      "--technique", "sta", "--model", "slab", "--preset", "skin1", "--light-dir", "0,0,1"],
     "--model slab: the match fits the STA parameters of --model sta"),
    # apply's counts for a technique that has none ran without a word (README: such a flag is an error)
    (["apply", str(MITSUBA / "skin_closeup_buffers.exr"), "-o", "never.exr", "--technique", "separable", "--albedo",
      "0.8,0.6,0.5", "--d-mm", "3,1.4,0.8", "--samples", "8"], "--samples is an option of burley, not of separable"),
    (["apply", str(MITSUBA / "skin_closeup_buffers.exr"), "-o", "never.exr", "--technique", "burley", "--albedo",
      "0.8,0.6,0.5", "--d-mm", "3,1.4,0.8", "--taps", "9"], "--taps is an option of jimenez, separable, not of burley"),
    (["advise", "--material", "skin1", "--max-delta-e", "1", "--depth-kind", "distance"],
     "--depth-kind distance reads --frame"),
])
def test_flags_a_mode_does_not_read_are_refused(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


# ---- what the API fuzz of stop 51 found: each failed, or answered wrongly, before --------------------------------

def _flat(h=8, w=8, z=1.0):
    return sj.Buffers(irradiance=jnp.ones((h, w, 3)), depth=jnp.full((h, w), z))


@pytest.mark.parametrize("make, message", [
    # a seed is an integer in [0, 2**32) for every technique that has one (hdrp's overflowed int32 inside JAX,
    # eevee-next's -1 overflowed uint32, 1.5 was rounded)
    (lambda: sj.hdrp(_flat(), sj.BurleyMaterial((0.8,) * 3, (1.0,) * 3), sj.Camera(100.0, 10.0), seed=-1),
     r"hdrp: seed must be an integer in \[0, 2\*\*32\), got -1"),
    (lambda: sj.HdrpPass(seed=1.5), r"hdrp: seed must be an integer in \[0, 2\*\*32\), got 1.5"),
    (lambda: sj.EeveeNextPass(seed=-1), r"eevee-next: seed must be an integer in \[0, 2\*\*32\), got -1"),
    (lambda: sj.EeveeNextPass(seed=2**32), r"eevee-next: seed must be an integer"),
    (lambda: sj.burley(_flat(), sj.BurleyMaterial((0.8,) * 3, (1.0,) * 3), sj.Camera(100.0, 10.0), seed="a"),
     r"burley: seed must be an integer in \[0, 2\*\*32\), got 'a'"),
    # technique objects are checked when made (reach_px and the batch's halos read them before any call)
    (lambda: sj.Burley(samples=0), "burley: samples must be a positive integer, got 0"),
    (lambda: sj.Burley(frames=0), "burley: frames must be a positive integer, got 0"),
    (lambda: sj.Burley(samples=True), "burley: samples must be a positive integer, got True"),
    # past int32 a jitted call stopped with an OverflowError from inside JAX (sss-jax report, bench, advise: a
    # traceback)
    (lambda: sj.Burley(samples=3_000_000_000),
     r"burley: samples must be at most 2147483647 \(the passes count in int32\), got 3000000000"),
    (lambda: sj.technique("burley", frames=2**31), "burley: frames must be at most 2147483647"),
    # a formulation of another technique is refused when the object is made, not at its first call
    (lambda: sj.Burley(impl="banded"), r"burley: impl='banded' is not one of \('auto', 'compacted', 'gather'"),
    (lambda: sj.Separable(impl="compacted"), r"separable: impl='compacted' is not one of \('auto', 'banded'"),
    (lambda: sj.Burley(seed=-1), r"burley: seed must be an integer in \[0, 2\*\*32\)"),
    (lambda: sj.Reference(radius_px=-3), "reference: radius_px must be a non-negative integer, got -3"),
    (lambda: sj.Reference(near_subsamples=0), "reference: near_subsamples must be a positive integer, got 0"),
    (lambda: sj.reference(_flat(), sj.BurleyMaterial((0.8,) * 3, (1.0,) * 3), sj.Camera(100.0, 10.0),
                          near_subsamples=-2), "near_subsamples must be a positive integer, got -2"),
    # an infinite Jimenez width made every pixel NaN
    (lambda: sj.JimenezParams(strength=0.5, falloff=0.5, sss_width=float("inf")), "sss_width must be finite and >= 0"),
])
def test_technique_options_fuzzed(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_hdrp_runs_a_sequence_whose_frame_seeds_pass_int32(tmp_path):
    # the batch mixes the frame number into the seed (uint32: frame 1 of seed 0 is 2654435761); hdrp's int32
    # conversion raised OverflowError at the second frame and ended the batch
    from sss_jax._batch import frame_seed

    sc = sj.demo_scene(12, 16)
    mat = sj.BurleyMaterial((0.8, 0.5, 0.4), (3.0, 1.4, 0.8))
    for k in range(3):
        _io.write_exr(tmp_path / f"shot_{k:04d}.exr", {
            **{c: np.asarray(sc.buffers.irradiance)[..., i] for i, c in enumerate("RGB")},
            "Z": np.where(np.isfinite(np.asarray(sc.buffers.depth)), np.asarray(sc.buffers.depth), -1.0)})
    assert frame_seed(0, 1) > 2**31
    with jax.enable_x64(False):  # as users run it (the suite enables x64, where int64 took the seed)
        r = sj.process_frames(str(tmp_path / "shot_*.exr"), "hdrp", mat, out_dir=tmp_path / "out", progress=False,
                              focal_px=float(sc.camera.focal_px), mm_per_unit=10.0)
    assert [f.status for f in r.frames] == ["done"] * 3, [f.message for f in r.frames]
    # the call itself, in this thread (the batch computes in threads of its own, where the context does not reach)
    with jax.enable_x64(False):
        for tech in (sj.hdrp, sj.eevee_next):
            assert np.all(np.isfinite(np.asarray(tech(sc.buffers, mat, sc.camera, seed=frame_seed(0, 1)))))


def test_a_camera_or_buffers_of_another_type_is_named():
    # None as the camera was "AttributeError: 'NoneType' object has no attribute 'focal_px'" from inside a pass
    sc = sj.demo_scene(8, 8)
    mat = sj.BurleyMaterial((0.8,) * 3, (1.0,) * 3)
    for name, call in (("burley", sj.burley), ("separable", sj.separable), ("reference", sj.reference),
                       ("jimenez", sj.jimenez)):
        with pytest.raises(TypeError, match=f"{name}: camera must be a Camera .* got NoneType"):
            call(sc.buffers, mat, None)
        with pytest.raises(TypeError, match=f"{name}: buffers must be a Buffers, got ndarray"):
            call(np.zeros((8, 8, 3)), mat, sc.camera)
    with pytest.raises(TypeError, match="translucency: camera must be a Camera"):
        sj.translucency(sc.buffers, sj.STAParams(), None, sc.back_light)


def test_an_empty_item_in_a_list_of_counts_or_thicknesses_is_refused(capsys):
    # "--taps 9,,17" ran 9 and 17, "--thickness-mm 1,,2" 1 and 2: the typo went unseen
    import argparse as _argparse

    from sss_jax.cli._options import comma_separated_counts

    with pytest.raises(_argparse.ArgumentTypeError, match="expected comma-separated positive integers, got '9,,17'"):
        comma_separated_counts("9,,17")
    assert comma_separated_counts("9, 17") == (9, 17)
    assert run_cli(["transmit", "--preset", "skin1", "--thickness-mm", "1,,2"]) == 2
    assert "expected comma-separated thicknesses in mm, got '1,,2'" in capsys.readouterr().err


def test_the_function_wrappers_name_an_unknown_option_as_the_registry_does():
    # sj.burley(..., sample=3) raised the constructor's "unexpected keyword argument"; technique("burley", sample=3)
    # listed the options: one message now
    sc = sj.demo_scene(6, 8)
    for fn, name in ((sj.burley, "burley"), (sj.separable, "separable"), (sj.hdrp, "hdrp"),
                     (sj.eevee_next, "eevee-next")):
        with pytest.raises(TypeError, match=f"technique '{name}' has no option\\(s\\) sample; its options: "):
            fn(sc.buffers, sj.BurleyMaterial([[0.8, 0.6, 0.5]] * 3, [[1.0, 0.5, 0.3]] * 3), sc.camera, sample=3)


def _preset_with(tmp_path, **sta):
    """A copy of the skin1 preset with its STA block's fields replaced."""
    data = json.loads(pathlib.Path(sj.load_preset("skin1").path).read_text())
    data["sta"] = {**data["sta"], **sta}
    path = tmp_path / "edited.json"
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize("call, error, message", [
    # a count given as a bool or a fraction was taken as 1 or truncated; a NumPy integer was refused
    (lambda: sj.engines.jimenez_kernel(0.5, 0.5, n_samples=3.9), ValueError, r"n_samples must be an integer >= 3, got 3.9"),
    (lambda: sj.engines.jimenez_kernel(0.5, 0.5, n_samples=True), ValueError, r"n_samples must be an integer >= 3"),
    (lambda: sj.to_engine("eevee", (0.8, 0.5, 0.3), (2, 1, 1), samples=0), ValueError,
     r"samples must be a positive integer, got 0"),
    (lambda: sj.to_engine("jimenez", (0.8, 0.5, 0.3), (2, 1, 1), n_samples=16.5), ValueError,
     r"n_samples must be an integer >= 3, got 16.5"),
    # "4.-2" read as (4, -2); a float cannot tell 2.9 from 2.90
    (lambda: sj.to_engine("eevee-next", (0.8, 0.5, 0.3), (2, 1, 1), blender_version="4.-2"), ValueError,
     r"blender_version must look like 4.2 or 5.1, got '4.-2'"),
    (lambda: sj.to_engine("eevee-next", (0.8, 0.5, 0.3), (2, 1, 1), blender_version=4.2), TypeError,
     r"blender_version must be a string like '4.2'"),
    # an option sss_jax's own parameters do not take was dropped
    (lambda: sj.to_engine("sss_jax", (0.8, 0.5, 0.3), (2, 1, 1), foo=1), ValueError,
     r"sss_jax's parameters take no options, got foo"),
    # a list for the parameters: "dictionary update sequence element #0"
    (lambda: sj.from_engine("unreal", [1, 2]), TypeError, r"unreal parameters must be a mapping .* got list"),
    (lambda: sj.convert("hdrp", "unreal", "x"), TypeError, r"hdrp parameters must be a mapping .* got str"),
    # an (N, 2, 2) table broadcast against the radii ("Incompatible shapes for broadcasting")
    (lambda: sj.TabulatedProfile(np.linspace(0.1, 1.0, 5), np.ones((5, 2, 2))), ValueError,
     r"r_mm must be \(N,\) with N >= 2 and R \(N, C\); got r_mm \(5,\), R \(5, 2, 2\)"),
    # AttributeError "'list' object has no attribute 'shape'" / "not enough values to unpack"
    (lambda: sj.normals_from_depth(None, sj.demo_scene(4, 4).camera), TypeError,
     r"normals_from_depth: depth must be an \(H, W\) array of depths, got NoneType"),
    (lambda: sj.normals_from_depth(np.ones(5), sj.demo_scene(4, 4).camera), ValueError,
     r"normals_from_depth: depth must be an \(H, W\) array of depths, got shape \(5,\)"),
    (lambda: sj.normals_from_depth(np.ones((4, 4)), 100.0), TypeError,
     r"normals_from_depth: camera must be a Camera, got float"),
    # 1 == True: a switch given 1 passed for True
    (lambda: sj.technique("separable", follow_surface=1), ValueError,
     r"separable: follow_surface=1 is not one of \(True, False\)"),
    # the engine passes' messages name their technique, as the others' do
    (lambda: sj.technique("hdrp", budget=0), ValueError, r"^hdrp: budget must be an integer in \[1, 1000\], got 0"),
    (lambda: sj.technique("hdrp", quality="x"), ValueError, r"^hdrp: quality='x' is not one of"),
    (lambda: sj.technique("eevee-next", frames=0), ValueError, r"^eevee-next: frames must be a positive integer, got 0"),
    (lambda: sj.technique("eevee-next", blender_version=4.2), TypeError, r"^eevee-next: blender_version must be a "),
])
def test_engine_profile_and_scene_helpers_name_what_is_wrong(call, error, message):
    with pytest.raises(error, match=message):
        call()


def test_jimenez_kernel_takes_a_numpy_integer_and_tap_offsets_too():
    # tap_offsets(np.int64(5)) was refused though spiral_samples takes NumPy integers
    offsets, _, _ = sj.tap_offsets(np.int64(5), 3.0)
    assert offsets.shape == (5,)
    assert sj.engines.jimenez_kernel(0.5, 0.5, n_samples=np.int64(11))[0].shape == (11,)
    with pytest.raises(ValueError, match="taps must be an odd positive integer"):
        sj.tap_offsets(True, 3.0)


def test_a_preset_field_that_is_not_a_number_is_named(tmp_path):
    # was "invalid preset: Value 'x' with dtype <U1 is not a valid JAX array type"
    with pytest.raises(sj.SSSInputError, match=r"edited.json: sta.power must be a number or a list of numbers, got 'x'"):
        sj.load_preset(_preset_with(tmp_path, power="x"))
    with pytest.raises(sj.SSSInputError, match=r"sta.scale must be a number or a list of numbers, got \[1, 'a', 1\]"):
        sj.load_preset(_preset_with(tmp_path, scale=[1, "a", 1]))


def test_an_albedo_for_a_preset_material_taken_whole_is_refused_not_dropped():
    # material_for("sta", preset, albedo=...) returned the STA parameters and dropped the albedo
    preset = sj.load_preset("skin1")
    with pytest.raises(ValueError, match="an albedo does not apply to the preset's STA parameters, which sta takes"):
        sj.material_for("sta", preset, albedo=(0.5, 0.5, 0.5))
    assert isinstance(sj.material_for("burley", preset, albedo=(0.5, 0.5, 0.5)), sj.BurleyMaterial)


def test_unreal_says_what_it_renders_for_a_channel_without_scattering():
    # d = 0 was written as Mean Free Path Color 0 without a word: UE clamps the colour to 0.009 and scatters it
    out = sj.to_engine("unreal", (0.8, 0.5, 0.3), (2.0, 1.0, 0.0))
    assert any("channel B has d = 0" in w and "clamps it to 0.009" in w for w in out.get("warnings", []))
    assert not any("d = 0" in w for w in sj.to_engine("unreal", (0.8, 0.5, 0.3), (2.0, 1.0, 0.5)).get("warnings", []))


def test_a_bool_is_not_a_count_anywhere(tmp_path):
    # scale_levels, tile_pixels and radius_px took True as 1 (their checks were isinstance(x, int), and a bool is
    # one); every count now goes through _checks.check_host_count
    sc = sj.demo_scene(6, 8)
    mat = sj.BurleyMaterial([0.8, 0.6, 0.5], [1.0, 0.5, 0.3])
    with pytest.raises(ValueError, match="scale_levels must be a positive integer, got True"):
        sj.separable(sc.buffers, mat, sc.camera, scale_levels=True)
    with pytest.raises(ValueError, match="tile_pixels must be a positive integer, got True"):
        sj.process_frames([str(tmp_path / "none.exr")], "burley", mat, out_dir=tmp_path / "o", tile_pixels=True,
                          progress=False)
    with pytest.raises(ValueError, match="radius_px must be a positive integer, got True"):
        sj.evaluate_frames([str(tmp_path / "none.exr")], mat, techniques=("burley",), radius_px=True)
    # the counts of the engines' conversions take a whole float (a parameter read from JSON), not a fraction
    assert sj.to_engine("eevee", (0.8, 0.5, 0.3), (2, 1, 1), samples=7.0)["Samples"] == 7


def test_a_display_image_given_as_a_frame_says_what_it_is(tmp_path):
    # an 8-bit PNG (a preview, a screenshot) passed where a frame belongs: OpenImageIO reads it, and the missing
    # depth is named with what the file is (before: only "missing depth channel(s) ... channels found: R, G, B")
    from sss_jax import _io

    path = tmp_path / "shot.png"
    write_ok = oiio.ImageOutput.create(str(path))
    spec = oiio.ImageSpec(6, 4, 3, oiio.UINT8)
    assert write_ok.open(str(path), spec) and write_ok.write_image(np.full((4, 6, 3), 128, np.uint8))
    write_ok.close()
    with pytest.raises(_io.SSSInputError, match=r"shot.png: missing depth channel\(s\) .* \(a PNG file, not OpenEXR"):
        _io.read_frame(path)


# ---- what a review of the commands found on 2026-12-07: each a traceback, a late failure or a silent choice ----


@pytest.mark.parametrize("argv, message", [
    # unknown names and bad values were "failed" presets (exit 1) after the folder, its README and schema were written
    (["fit", "--material", "nosuch"], "unknown material(s) 'nosuch'; known: "),
    (["fit", "--name", "velvet", "--albedo", "1,0.7,0.5", "--d-mm", "3,2,1"], "albedo must be 3 values in (0, 1)"),
    # an output that cannot be a folder was FileNotFoundError's traceback
    (["fit", "--material", "skin", "--out", "/proc/sss_jax_cannot"], "output directory is not writable"),
    # two colours for one: the linear one was taken without a word
    (["convert", "--from", "hdrp", "--to", "sss_jax", "--albedo", "0.8", "--scattering-color", "0.2",
      "--scattering-color-srgb", "0.9"], "are two colours"),
    # one photon's standard error is undefined: it printed +- 0.00000
    (["montecarlo", "--albedo", "0.9", "--photons", "1", "--json", "mc.json"], "photons must be an integer >= 2"),
])
def test_commands_refuse_bad_input_before_any_work_and_write_nothing(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    out = ["--out", "fits"] if argv[0] == "fit" and "--out" not in argv else []
    assert main([*argv, *out]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_report_refuses_sta_s_flags_where_no_sta_runs(tmp_path, capsys):
    # --thickness -1 (and --light-dir) with --techniques separable ran with exit 0: the flag was dropped unsaid
    frame = tmp_path / "f.exr"
    good_exr(frame)
    base = ["report", str(frame), "--out", str(tmp_path / "rep"), "--d-mm", "3,1.4,0.8", "--focal-px", "50"]
    assert main([*base, "--techniques", "separable", "--thickness", "-1"]) == 2
    assert "--thickness: for STA, and --techniques separable runs no STA" in capsys.readouterr().err
    assert main([*base, "--thickness", "1"]) == 2  # the default techniques, STA left out: no light
    assert "STA needs --light-dir X,Y,Z too" in capsys.readouterr().err
    assert not (tmp_path / "rep").exists()


def test_fit_render_checks_its_report_s_window_before_the_fit(tmp_path, capsys):
    # --radius-px 0 failed in the report after the whole fit (~25 s), with a traceback, and wrote no report
    argv = ["fit", "--render", str(MITSUBA / "skin_closeup_buffers.exr"), "--truth",
            str(MITSUBA / "skin_closeup_truth.exr"), "--technique", "burley", "--preset", "skin1",
            "--report", str(tmp_path / "rep"), "--radius-px", "0", "--json", str(tmp_path / "fit.json")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--radius-px must be a positive integer, got 0" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_advise_refuses_a_scene_size_the_demo_refuses(capsys):
    # 100000x100000 ended in numpy's _ArrayMemoryError traceback; the demo's bounds hold for both
    with pytest.raises(SystemExit) as exc:
        main(["advise", "--material", "marble", "--size", "100000x100000"])
    assert exc.value.code == 2
    assert "--size must be between 8x8 and 8192x8192" in capsys.readouterr().err


def test_a_jimenez_kernel_of_strength_0_converts_to_no_scattering():
    # strength 0 is the centre tap alone (the identity): the bounded search gave d = 1.97 mm, while 0.001 gave 0.039
    from sss_jax.engines._registry import REGISTRY

    _, d = REGISTRY["jimenez"].from_engine({"sssWidth": 0.01, "strength": [0.0, 0.0, 0.001],
                                                 "falloff": [0.5, 0.5, 0.5]})
    assert d[0] == 0.0 and d[1] == 0.0 and 0 < d[2] < 0.1


_LIGHT = sj.DirectionalLight([0.0, 0.0, 1.0])


@pytest.mark.parametrize("call, error, message", [
    # a per-channel distortion bent the normal's x, y, z; a per-channel power ran along the image's columns
    (lambda: sj.STAParams(distortion=(0.1, 0.5, 0.9)), ValueError, r"distortion must be one number .* shape \(3,\)"),
    (lambda: sj.STAParams(power=(1.0, 4.0, 16.0)), ValueError, r"power must be one number .* shape \(3,\)"),
    (lambda: sj.STAParams(scale=(1.0, 2.0)), ValueError, r"scale must be one number or 3 \(R, G, B\), got shape \(2,\)"),
    (lambda: sj.STAParams(power="4"), TypeError, r"STAParams: power must be a number, got '4'"),
    (lambda: sj.STAParams(distortion=0.7, dtype=jnp.int32), TypeError, r"dtype must be a floating type"),
    # True read as 1.0
    (lambda: sj.STAParams(power=True), TypeError, r"power must be a number, not a bool"),
    (lambda: sj.DirectionalLight((True, False, False)), TypeError, r"light direction must be numbers, not bools"),
    (lambda: sj.DirectionalLight((0.0, 0.0, 1.0), colour=(1.0, 1.0)), ValueError, r"light colour must be one number or 3"),
    (lambda: sj.Camera(True, True), TypeError, r"camera focal_px must be a number, not a bool"),
    (lambda: sj.BurleyMaterial(albedo=(0.5, 0.5, True), d_mm=(1.0, 1.0, 1.0)), TypeError, r"albedo must be numbers, not bools"),
    (lambda: sj.translucency(sj.demo_scene(4, 4).buffers, sj.STAParams(), sj.Camera(100.0), _LIGHT, thickness=True),
     ValueError, r"thickness must be >= 0 scene units .* got True"),
    # Python's "missing 1 required positional argument"; an unknown option's bare __init__ TypeError
    (lambda: sj.technique("sta"), TypeError, r"technique 'sta' needs light=DirectionalLight"),
    (lambda: sj.Burley().replace(bogus=1), TypeError, r"technique 'burley' has no option\(s\) bogus; its options: "),
    (lambda: sj.load_preset(123), TypeError, r"load_preset: give a preset's name or a path"),
    # an empty list did nothing and wrote a manifest; an int gave "'int' object is not iterable"
    (lambda: sj.process_frames([], "burley", sj.BurleyMaterial(0.5, 1.0), out_dir="/nonexistent/never", progress=False),
     sj.SSSInputError, r"no input frames: the list is empty"),
    (lambda: sj.process_frames(5, "burley", sj.BurleyMaterial(0.5, 1.0), out_dir="/nonexistent/never", progress=False),
     TypeError, r"input frames: give a path, a glob pattern or a list of them, got int"),
    (lambda: sj.process_frames(["a.exr"], "burley", sj.BurleyMaterial(0.5, 1.0), out_dir="/nonexistent/never",
                               png="yes", progress=False), TypeError, r"png must be True or False, got 'yes'"),
    (lambda: sj.process_frames(["a.exr"], "sta", (sj.STAParams(), _LIGHT), out_dir="/nonexistent/never",
                               sta_thickness=True, progress=False), TypeError, r"sta_thickness must be a number"),
    # advise from Python: "min() arg is an empty sequence", an IndexError, the camera's mm_per_unit
    (lambda: sj.advise("skin", candidates=[]), ValueError, r"candidates: give at least one"),
    (lambda: sj.advise("skin", repeats=0), ValueError, r"repeats must be a positive integer, got 0"),
    (lambda: sj.advise("skin", scene_scale=-1), ValueError, r"scene_scale must be a finite positive number"),
    (lambda: sj.evaluate_frames(["a.exr"], sj.BurleyMaterial(0.5, 1.0), techniques=["burley"], repeats=True), ValueError,
     r"repeats must be an integer >= 0, got True"),
])
def test_sta_cameras_lights_and_the_python_api_name_what_is_wrong(call, error, message):
    with pytest.raises(error, match=message):
        call()


@pytest.mark.parametrize("bad, message", [
    ({"scale": -1.0}, "STA scale must be"), ({"ambient": -1.0}, "STA ambient must be"),
    ({"distortion": -3.0}, "STA distortion must be"), ({"ambient": float("nan")}, "STA ambient must be"),
])
def test_sta_checks_its_parameters_under_jit_too(bad, message):
    # under jit only power and thickness_mm were checked: scale -1 gave negative light, a NaN ambient a NaN image
    scene = sj.demo_scene(6, 8)
    good = {"distortion": 0.2, "power": 4.0, "scale": 1.0, "ambient": 0.1, "thickness_mm": 1.0}

    @jax.jit
    def run(values):
        return sj.translucency(scene.buffers, sj.STAParams(**values), scene.camera, scene.back_light)

    run({k: jnp.asarray(v) for k, v in good.items()})  # the good values pass
    with pytest.raises(Exception, match=message):
        jax.block_until_ready(run({k: jnp.asarray(v) for k, v in {**good, **bad}.items()}))
    # the constant thickness, traced (a frame without a thickness buffer): -1 gave ~22,000 times the light
    thin = sj.Buffers(irradiance=scene.buffers.irradiance, depth=scene.buffers.depth, normal=scene.buffers.normal)
    with pytest.raises(Exception, match="thickness must be"):
        jax.block_until_ready(jax.jit(lambda t: sj.translucency(thin, sj.STAParams(), scene.camera,
                                                               scene.back_light, thickness=t))(jnp.asarray(-1.0)))


def test_a_preset_sta_block_names_a_parameter_it_does_not_have(tmp_path):
    # "distorsion" left the distortion at its default without a word; a per-channel power loaded
    with pytest.raises(sj.SSSInputError, match=r"sta has no parameter\(s\) distorsion; its parameters: distortion"):
        sj.load_preset(_preset_with(tmp_path, distorsion=0.9))
    with pytest.raises(sj.SSSInputError, match=r"invalid preset: STAParams: power must be one number"):
        sj.load_preset(_preset_with(tmp_path, power=[1.0, 2.0, 3.0]))


def test_a_numpy_count_is_kept_as_a_python_integer():
    # Burley(samples=np.int64(8)) kept the NumPy integer: equinox warned "A JAX array is being set as static!" and
    # options() (what a manifest records) was not JSON
    t = sj.Burley(samples=np.int64(8))
    assert type(t.samples) is int and json.loads(json.dumps(t.options()))["samples"] == 8


def test_evaluate_frames_takes_one_technique_by_name_as_a_string():
    # techniques="burley" ran through its letters: "unknown technique(s) ['b']"
    with pytest.raises(sj.SSSInputError, match=r"no such file|not found|cannot read"):
        sj.evaluate_frames(["/nonexistent/a.exr"], sj.BurleyMaterial(0.5, 1.0), techniques="burley", repeats=0)


def test_convert_refuses_an_engine_value_that_is_not_finite(tmp_path, capsys):
    # d = 1e308 mm gave HDRP a "Max Radius (mm)" of inf, written as Infinity (not JSON) with exit 0; Blender's
    # overflowing radius printed numpy's RuntimeWarning before the clean error
    import warnings

    from sss_jax.cli import main

    out = tmp_path / "inf.json"
    assert main(["convert", "--from", "sss_jax", "--to", "hdrp", "--albedo", "0.8,0.6,0.5", "--d-mm", "1e308,1.4,0.8",
                 "--json", str(out)]) == 2
    assert "hdrp: Max Radius (mm) would be inf" in capsys.readouterr().err and not out.exists()
    with pytest.raises(ValueError, match=r"hdrp: Max Radius \(mm\) would be inf"):
        sj.to_engine("hdrp", (0.8, 0.6, 0.5), (1e308, 1.4, 0.8))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match="d_mm must be finite"):
            sj.convert("blender", "sss_jax", {"Subsurface Color": (0.8, 0.6, 0.5),
                                              "Subsurface Radius": (1e306, 1.0, 1.0), "Subsurface Scale": 100.0})
