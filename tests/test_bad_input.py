"""Bad input everywhere a user can reach it: each case checks the message, the exit status and that nothing was
left behind."""

import re

import jax.numpy as jnp
import numpy as np
import OpenImageIO as oiio
import pytest

import sss_jax as sj
from sss_jax.cli import main

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
    (MATERIAL + ["--taps", "4"], "--taps must be odd"),
    (MATERIAL + ["--samples", "0"], "--samples must be >= 1"),
    (["--technique", "burley", "--d-mm=-1,1,1"], r"d_mm must lie in \[0.0, inf\]"),
    (["--technique", "burley", "--d-mm", "nan,1,1"], r"d_mm must lie in .*not be NaN"),
    (["--technique", "burley", "--d-mm", "1,1,1", "--albedo", "1.5,0.5,0.5"], r"albedo must lie in \[0.0, 1.0\]"),
    (["--technique", "burley", "--d-mm", "1,2"], "expected three comma-separated numbers"),
    (MATERIAL + ["--focal-px=-3"], "--focal-px must be a finite positive number"),
    (MATERIAL + ["--mm-per-unit", "0"], "--mm-per-unit must be a finite positive number"),
    (["--technique", "burley", "--mfp-mm=-2,1,1"], r"mfp_mm must lie in"),
    (["--technique", "sta", "--light-dir", "0,0,0"], "light direction must be a finite non-zero vector"),
    (["--technique", "sta", "--light-dir", "0,0,1", "--sta-thickness-mm", "0,1,1"], r"thickness_mm must lie in"),
]


@pytest.mark.parametrize("argv, message", ARG_CASES)
def test_bad_arguments(tmp_path, capsys, argv, message):
    inp = good_exr(tmp_path / "good.exr")
    out = tmp_path / "out" / "o.exr"
    out.parent.mkdir()
    assert run_cli(["apply", str(inp), "-o", str(out)] + argv) == 2
    assert re.search(message, capsys.readouterr().err)
    assert list(out.parent.iterdir()) == []


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
    assert run_cli(["apply", str(inp), "-o", str(out)] + MATERIAL) == 1
    assert "output directory does not exist" in capsys.readouterr().err
    assert not out.parent.exists()


def test_invalid_channel_maps(tmp_path, capsys):
    inp = good_exr(tmp_path / "good.exr")
    for text, message in [("{not json", "invalid channel map"), ('{"colour": "R"}', "unknown buffer 'colour'"),
                          ('{"depth": ["Z", "Z"]}', r"'depth' needs 1 channel")]:
        cmap = tmp_path / "map.json"
        cmap.write_text(text)
        out = tmp_path / "o.exr"
        assert run_cli(["apply", str(inp), "-o", str(out), "--channel-map", str(cmap)] + MATERIAL) == 1
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
     "irradiance has negative values"),
    (lambda: sj.BurleyMaterial([0.5, 0.5], [1, 1, 1]), r"albedo must have 3 values"),
    (lambda: sj.TwoGaussianMaterial([1, 1, 1], [1.2, 0, 0], [1, 1, 1], [2, 2, 2]), r"w must lie in \[0.0, 1.0\]"),
    (lambda: sj.burley(sj.Buffers(irradiance=jnp.ones((4, 4, 3)), depth=jnp.ones((4, 4))),
                       sj.TwoGaussianMaterial([1, 1, 1], [1, 1, 1], [1, 1, 1], [1, 1, 1]), sj.Camera(10.0)),
     "burley needs a BurleyMaterial"),
    (lambda: sj.Camera(-1.0), "focal_px must be a finite positive number"),
    (lambda: sj.get_technique("blur"), "valid techniques: sta, separable, burley, reference"),
])
def test_python_api_bad_input(make, message):
    with pytest.raises((ValueError, TypeError), match=message):
        make()
