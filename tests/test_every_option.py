"""Every option on every command (issue #26), the engines' passes in report, advise and bench (issue #29), advise
against a truth (issue #27), and the cost per pixel as each shader executes it."""

import json
import math

import jax.numpy as jnp
import numpy as np
import OpenImageIO as oiio
import pytest
from scipy.optimize import brentq

import sss_jax as sj
from sss_jax._cost import frame_cost
from sss_jax.cli import main

FOCAL = 200.0
MM_PER_UNIT = 10.0
DEPTH = 30.0  # scene units: 200 / (30 * 10) = 2/3 px per mm


def write_frame(path, h=24, w=32, *, irradiance=None, ids=True):
    """A step edge on a plane at depth 30, written with raw OpenImageIO calls; id 0 in the first three columns."""
    e = np.zeros((h, w, 3), np.float32) if irradiance is None else irradiance
    if irradiance is None:
        e[:, w // 2:] = (1.0, 0.8, 0.6)
    ch = {"R": e[..., 0], "G": e[..., 1], "B": e[..., 2], "Z": np.full((h, w), DEPTH, np.float32)}
    if ids:
        k = np.ones((h, w), np.float32)
        k[:, :3] = 0
        ch["id"] = k
    data = np.stack([np.asarray(v, np.float32) for v in ch.values()], -1)
    spec = oiio.ImageSpec(w, h, data.shape[-1], oiio.FLOAT)
    spec.channelnames = tuple(ch)
    spec.attribute("sss_jax:focal_px", FOCAL)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(data)
    out.close()
    return e


def write_rgb(path, rgb):
    spec = oiio.ImageSpec(rgb.shape[1], rgb.shape[0], 3, oiio.FLOAT)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(np.asarray(rgb, np.float32))
    out.close()


def read_rgb(path):
    inp = oiio.ImageInput.open(str(path))
    img = inp.read_image(oiio.FLOAT)
    inp.close()
    return np.asarray(img)[..., :3].astype(np.float64)


# ---- the cost per pixel as the engines' shaders execute it --------------------------------------------------------

def _burley_cdf_radius(fraction: float) -> float:
    """Burley's radius (units of d) holding ``fraction`` of the energy: 1 - e^-x / 4 - 3 e^(-x/3) / 4 = fraction
    (the CDF of Christensen & Burley 2015, eq. 3 integrated), solved by bisection."""
    return brentq(lambda x: 1 - math.exp(-x) / 4 - 3 * math.exp(-x / 3) / 4 - fraction, 1e-9, 200.0)


def test_frame_cost_counts_what_each_engine_shader_executes():
    # two depths: near pixels whose HDRP footprint exceeds the budget, far ones below it
    h, w = 8, 10
    depth = np.full((h, w), 30.0, np.float32)
    depth[:, 5:] = 600.0
    b = sj.Buffers(irradiance=jnp.ones((h, w, 3), jnp.float32), depth=jnp.asarray(depth))
    cam = sj.Camera(FOCAL, MM_PER_UNIT)
    mat = sj.BurleyMaterial((0.8, 0.6, 0.5), (3.0, 1.5, 0.75))
    # HDRP (SubsurfaceScattering.compute): n = min(floor(pi r^2 / 4), budget), r = 0.997-energy radius in px
    r_units = _burley_cdf_radius(0.997)
    n = [min(math.floor(math.pi * (r_units * 3.0 * FOCAL / (z * MM_PER_UNIT)) ** 2 / 4), 40) for z in (30.0, 600.0)]
    assert n[0] == 40 and 1 <= n[1] < 40, n  # the frame holds both cases
    c = frame_cost(sj.HdrpPass(quality="medium"), b, mat, cam)
    assert c["samples"] == pytest.approx(np.mean(n))
    assert c["fetches"] == pytest.approx(np.mean(n) + 1)  # point fetches and the centre
    c_low = frame_cost(sj.HdrpPass(quality="low"), b, mat, cam)
    assert c_low["samples"] == pytest.approx(np.mean([min(k, 20) for k in n]))
    # EEVEE Next: 16 samples per TAA frame wherever the scaled radius exceeds one pixel, here every pixel
    e = frame_cost(sj.EeveeNextPass(frames=8), b, mat, cam)
    assert (e["samples"], e["fetches"], e["frames"], e["active_fraction"]) == (16, 17, 8, 1.0)
    # Jimenez (SSSSBlurPS): two passes of the centre and taps - 1 linear fetches of 2 texels each
    j = frame_cost(sj.JimenezPass(taps=11), b, sj.BurleyMaterial((0.8, 0.6, 0.5), (3.0, 1.5, 0.75)), cam)
    assert (j["samples"], j["fetches"]) == (22, 2 * (1 + 2 * 10))
    # Burley: its bilinear fetches (4 texels) plus the centre on every pixel over its footprint threshold
    assert frame_cost(sj.Burley(samples=8), b, mat, cam)["fetches"] == 8 * 4 + 1
    assert frame_cost(sj.Reference(), b, mat, cam) is None  # a dense window, not a real-time pass


# ---- bench ------------------------------------------------------------------------------------------------------

def _capture_run_bench(monkeypatch):
    import sss_jax._bench as bench

    seen = {}

    class Stop(Exception):
        pass

    def fake(*, quick=False, repeats=3, progress=None, techniques=None, technique_options=None):
        seen.update(techniques=techniques, technique_options=technique_options)
        raise Stop

    monkeypatch.setattr(bench, "run_bench", fake)
    return seen, Stop


def test_bench_takes_a_technique_and_its_options(monkeypatch, capsys, as_users_run_it):
    seen, stop = _capture_run_bench(monkeypatch)
    with pytest.raises(stop):
        main(["bench", "--quick", "--technique", "separable", "--taps", "9", "--border", "leaves"])
    assert seen["techniques"] == ["separable"]
    assert seen["technique_options"]["separable"] == {"taps": (9,), "border": "leaves"}
    assert seen["technique_options"]["reference"] == {"border": "leaves"}  # the error columns' reference: same rule
    seen.clear()
    with pytest.raises(stop):
        main(["bench", "--technique", "hdrp,eevee-next,jimenez", "--quality", "high", "--frames", "16", "--taps", "17"])
    opts = seen["technique_options"]
    assert opts["hdrp"] == {"quality": "high", "frames": 16} and opts["eevee-next"] == {"frames": 16}
    assert opts["jimenez"] == {"taps": (17,)}
    # flags that reach no technique of the run, bad counts: exit 2, the flag named
    for argv, message in ((["--quality", "high"], "--quality is an option of hdrp"),
                          (["--technique", "hdrp", "--taps", "9"], "--taps: none of the techniques run"),
                          (["--technique", "nonesuch"], "unknown technique(s) nonesuch")):
        try:
            rc = main(["bench", "--quick"] + argv)
        except SystemExit as exc:
            rc = exc.code
        assert rc == 2 and message in capsys.readouterr().err, argv


def test_bench_runs_the_chosen_configurations_with_their_cost(bench_timed_together):
    from sss_jax._bench import run_bench

    res = run_bench(repeats=1, grid=dict(resolutions=[(24, 16)], ratio_resolution=(24, 16), error_size=(16, 24),
                                         pattern_size=16), techniques=["hdrp"],
                    # the reference's own options reach the error columns' reference (a small window: cheap)
                    technique_options={"hdrp": {"quality": "low", "frames": 2},
                                       "reference": {"border": "leaves", "radius_px": 6}})
    (row,) = res["rows"]
    assert row["label"] == "hdrp quality=low frames=2" and row["count"] is None
    assert row["options"] == {"quality": "low", "frames": 2}
    assert row["cost_per_pixel"]["samples"] <= 20 and row["cost_per_pixel"]["frames"] == 2  # the low budget
    assert 0 < row["errors"]["demo"] < 1 and row["ms_per_frame"] > 0
    assert res["ratios"] == {} and "hdrp quality=low frames=2 ms" in res["other_ratios"]
    # its ratios to the peers timed side by side with them (one after the other, a slow minute fell on one side)
    assert "hdrp quality=low frames=2 vs cv2.filter2D_25x25" in res["other_ratios"]
    assert any({"hdrp quality=low frames=2", "cv2.filter2D_25x25", "cv2.sepFilter2D_25"} <= names
               for names in bench_timed_together)
    assert res["technique_options"]["reference"] == {"border": "leaves", "radius_px": "6"}


# ---- advise -----------------------------------------------------------------------------------------------------

def test_advise_reaches_the_technique_options_and_the_engines(tmp_path, capsys):
    out = tmp_path / "advice.json"
    rc = main(["advise", "--material", "wax", "--max-delta-e", "50", "--size", "32x24", "--repeats", "1",
               "--technique", "burley,hdrp", "--samples", "8", "--border", "leaves", "--quality", "low",
               "--json", str(out)])
    printed = capsys.readouterr().out
    assert rc == 0, printed
    doc = json.loads(out.read_text())
    # the options of the objects that ran (changed from their defaults), in the JSON and the table
    by_label = {c["label"]: c for c in doc["candidates"]}
    assert set(by_label) == {"local", "burley 8 border=leaves", "hdrp quality=low"}
    assert by_label["burley 8 border=leaves"]["options"] == {"border": "leaves"}
    assert by_label["hdrp quality=low"]["options"] == {"quality": "low"} and by_label["hdrp quality=low"]["count"] is None
    assert "burley 8 border=leaves" in printed and "hdrp quality=low" in printed
    assert all(c["delta_e"] < by_label["local"]["delta_e"] for c in doc["candidates"] if c["technique"] != "local")


def test_advise_against_a_truth_flags_what_is_worse_than_local_shading(tmp_path, capsys, as_users_run_it):
    """Issue #27: `advise --truth`: a truth equal to local shading (albedo x irradiance) makes every scattering
    candidate worse than local shading; the table and the JSON say which."""
    frame = tmp_path / "frame.exr"
    e = write_frame(frame)
    albedo = np.asarray([0.8, 0.6, 0.5], np.float32)
    ids = np.ones(e.shape[:2])
    ids[:, :3] = 0
    truth = np.where(ids[..., None] > 0, albedo * e, e)
    write_rgb(tmp_path / "truth.exr", truth)
    out = tmp_path / "a.json"
    rc = main(["advise", "--frame", str(frame), "--truth", str(tmp_path / "truth.exr"), "--albedo", "0.8,0.6,0.5",
               "--d-mm", "3,1.5,0.75", "--mm-per-unit", str(MM_PER_UNIT), "--max-delta-e", "100", "--repeats", "1",
               "--technique", "separable,burley", "--taps", "9", "--samples", "8", "--json", str(out)])
    printed = capsys.readouterr().out
    assert rc == 0, printed
    doc = json.loads(out.read_text())
    assert doc["against"] == "truth"
    local = [c for c in doc["candidates"] if c["technique"] == "local"][0]
    assert local["delta_e"] == pytest.approx(0.0, abs=1e-6)
    assert sorted(doc["worse_than_local_shading"]) == ["burley 8", "separable 9"]
    assert "worse than local shading against the truth: " in printed and "(worse than local shading)" in printed
    # a truth needs the frame it renders; the demo's flags do not go with a frame
    for argv, message in ((["--material", "wax", "--truth", str(tmp_path / "truth.exr")], "--truth needs --frame"),
                          (["--frame", str(frame), "--d-mm", "1,1,1", "--size", "32x24"], "--size is for the demo"),
                          (["--material", "wax", "--d-mm", "1,1,1"], "either --material or --d-mm")):
        assert main(["advise", "--max-delta-e", "1"] + argv) == 2
        assert message in capsys.readouterr().err, argv


# ---- report -----------------------------------------------------------------------------------------------------

def test_report_shows_the_engines_passes_with_their_cost(tmp_path, capsys, as_users_run_it):
    frame, truth_path = tmp_path / "frame.exr", tmp_path / "truth.exr"
    e = write_frame(frame)
    truth = np.where(np.arange(e.shape[1])[None, :, None] >= 3, 0.7 * e + 0.01, e)  # any render of that view
    write_rgb(truth_path, truth)
    rc = main(["report", str(frame), "--out", str(tmp_path / "rep"), "--truth", str(truth_path),
               "--albedo", "0.8,0.6,0.5", "--d-mm", "3,1.5,0.75", "--mm-per-unit", str(MM_PER_UNIT),
               "--techniques", "burley,hdrp:quality=low,hdrp:quality=high,eevee-next,jimenez", "--samples", "8",
               "--frames", "2", "--repeats", "0", "--no-progress"])
    err = capsys.readouterr()
    assert rc == 0, err.err
    doc = json.loads((tmp_path / "rep" / "report.json").read_text())
    rows = {t["label"]: t for t in doc["techniques"]}
    assert {"burley 8", "hdrp quality=low frames=2", "hdrp quality=high frames=2", "eevee-next",
            "jimenez"} <= set(rows)
    # the flags reach every technique that has the option, an entry's own options only that entry
    assert rows["eevee-next"]["options"] == {"frames": 2} and rows["burley 8"]["options"] == {"frames": 2}
    assert rows["jimenez"]["options"] == {}
    # the cost per pixel as each shader executes it: HDRP's budget, EEVEE Next's 16, Jimenez's 2 x 17 taps
    assert rows["hdrp quality=low frames=2"]["cost_per_pixel"]["samples"] <= 20
    assert rows["hdrp quality=high frames=2"]["cost_per_pixel"]["samples"] > 20
    assert rows["eevee-next"]["cost_per_pixel"]["samples"] == 16
    assert rows["jimenez"]["cost_per_pixel"]["samples"] == 34
    # each engine's error against the truth, from the image the report wrote (NumPy, float64)
    mask = np.zeros(e.shape[:2], bool)
    mask[:, 3:] = True
    for label in ("hdrp quality=low frames=2", "jimenez"):
        img = read_rgb(tmp_path / "rep" / "images" / "frame" / (label.replace(" ", "_") + ".exr"))
        want = np.linalg.norm(img[mask] - truth[mask]) / np.linalg.norm(truth[mask])
        assert rows[label]["vs_truth"]["rel_l2"] == pytest.approx(want, rel=1e-5)
        assert rows[label]["worse_than_local_shading"]["vs_truth"] is not None
        # the terminal says it too, under the run's cost line (before, only the HTML and the JSON had the errors)
        line = err.out.split(f"  {label}: ", 1)[1].splitlines()[1]
        assert f"vs truth rel L2 {rows[label]['vs_truth']['rel_l2']:.4f}" in line and abs(
            float(line.split("vs truth rel L2 ")[1][:6]) - want) < 6e-5, line
    assert "  local shading (no SSS): vs reference rel L2 " in err.out and "vs truth rel L2" in err.out
    page = (tmp_path / "rep" / "report.html").read_text()
    assert "fetches / px" in page and "hdrp quality=high frames=2" in page
    assert "hdrp quality=low frames=2" in err.out  # the terminal lists each run's cost


@pytest.mark.parametrize("spec, message", [
    ("hdrp:nonesuch=1", "hdrp has no option 'nonesuch'"),
    ("hdrp:quality=ultra", "quality: expected one of high, low, medium"),
    ("jimenez,unknown", "unknown technique 'unknown'"),
    ("burley:samples=8", "give them as --samples"),
])
def test_report_technique_entries_bad_options(tmp_path, capsys, as_users_run_it, spec, message):
    frame = tmp_path / "frame.exr"
    write_frame(frame, h=12, w=16)
    rc = main(["report", str(frame), "--out", str(tmp_path / "rep"), "--d-mm", "1,1,1", "--techniques", spec,
               "--no-progress"])
    assert rc == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "rep").exists()


def test_an_integer_option_whose_default_is_none_parses_as_an_integer(tmp_path, capsys, as_users_run_it):
    # hdrp's budget (``int | None``, default None) was parsed as a float, which its check refuses: every value,
    # 50 included, failed with "budget must be an integer, got 50.0" (apply, report, advise, bench)
    frame = tmp_path / "frame.exr"
    write_frame(frame, h=12, w=16)

    def apply(budget):
        try:
            return main(["apply", str(frame), "-o", str(tmp_path / f"o{budget}.exr"), "--d-mm", "1,1,1",
                         "--technique", "hdrp", "--budget", budget])
        except SystemExit as exc:  # argparse's refusal
            return exc.code

    assert apply("50") == 0 and read_rgb(tmp_path / "o50.exr").shape == (12, 16, 3)
    for value, message in (("0", "budget must be an integer in [1, 1000], got 0"),
                           ("5000", "budget must be an integer in [1, 1000]"),
                           ("2.5", "--budget: expected an integer, got '2.5'")):
        capsys.readouterr()
        assert apply(value) == 2
        assert message in capsys.readouterr().err
    rc = main(["report", str(frame), "--out", str(tmp_path / "rep"), "--d-mm", "1,1,1", "--techniques",
               "hdrp:budget=24", "--no-progress", "--no-images", "--repeats", "1"])
    assert rc == 0, capsys.readouterr().err


def test_report_jimenez_taps_given_are_checked(tmp_path, capsys, as_users_run_it):
    frame = tmp_path / "frame.exr"
    write_frame(frame, h=12, w=16)
    rc = main(["report", str(frame), "--out", str(tmp_path / "rep"), "--d-mm", "1,1,1", "--techniques",
               "separable,jimenez", "--taps", "9", "--no-progress"])
    assert rc == 2 and "--taps: jimenez: taps=9 is not one of (11, 17, 25)" in capsys.readouterr().err
    # a count that none of the report's techniques takes is refused, not dropped (before, the report ran burley's own
    # sweep and said nothing of --taps 5; found by a review, 2026-12-07)
    for techniques, flag in (("burley", "--taps"), ("separable", "--samples")):
        rc = main(["report", str(frame), "--out", str(tmp_path / "rep2"), "--d-mm", "1,1,1", "--techniques",
                   techniques, flag, "5", "--no-progress"])
        assert rc == 2 and f"{flag}: none of the techniques run ({techniques}) has {flag[2:]}" in \
            capsys.readouterr().err
        assert not (tmp_path / "rep2").exists()


# ---- fit --render -------------------------------------------------------------------------------------------------

def test_fit_render_passes_the_technique_options(tmp_path, monkeypatch, capsys, as_users_run_it):
    import sss_jax._match as match

    seen = {}

    class Stop(Exception):
        pass

    real = match.match_render

    def fake(frames, material, **kw):
        seen.update(kw)
        raise Stop

    fake.__signature__ = __import__("inspect").signature(real)
    monkeypatch.setattr(match, "match_render", fake)
    frame, truth = tmp_path / "frame.exr", tmp_path / "truth.exr"
    e = write_frame(frame, h=12, w=16)
    write_rgb(truth, 0.8 * e)
    with pytest.raises(Stop):
        main(["fit", "--render", str(frame), "--truth", str(truth), "--technique", "burley", "--albedo", "0.8,0.8,0.8",
              "--d-mm", "1,1,1", "--mm-per-unit", str(MM_PER_UNIT), "--samples", "4", "--border", "leaves",
              "--pattern", "fixed"])
    assert seen["technique"] == "burley" and seen["technique_options"] == {
        "burley": {"border": "leaves", "pattern": "fixed"}}
    # the fit builds the technique with them, over its own options (bilinear fetches: smooth in d)
    technique, _ = match._fit_technique("burley", {"border": "leaves", "pattern": "fixed"}, samples=4)
    assert (technique.border, technique.pattern, technique.samples, technique.interpolation) == (
        "leaves", "fixed", 4, "bilinear")
    with pytest.raises(ValueError, match="has no option"):
        match._fit_technique("burley", {"quality": "low"}, samples=4)


@pytest.mark.parametrize("command", ["apply", "report", "advise"])
def test_a_technique_flags_help_names_each_technique_once(command, capsys):
    # the flags' help is "[hdrp] <what it does>"; before, the engines' options carried their name in their own
    # text as well: "[hdrp] hdrp: texturing mode", "jimenez: jimenez: SSSS_FOLLOW_SURFACE"
    import re

    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
    assert "--quality" in text and "--follow-surface" in text
    repeated = re.findall(r"\b(sta|separable|burley|reference|hdrp|eevee-next|jimenez): \1:", text)
    assert not repeated, repeated
    assert not re.search(r"\[(hdrp|eevee-next|jimenez)\] \1:", text), text


def test_separable_counts_its_taps_once_per_pass_as_jimenez_does():
    # a separable pass of 9 taps runs them twice (horizontal, then vertical): 18 taps a pixel beside its 2 x (1 + 2 x
    # 8) = 34 texels (the 8 taps off the centre as linear fetches of 2 texels, the centre once per pass: it was
    # counted a second time as a tap, 38), as jimenez's 2 x 17 are 34; before, 9
    from sss_jax._cost import frame_cost

    sc = sj.demo_scene(24, 32)
    mat = sj.BurleyMaterial((0.8, 0.6, 0.5), (3.0, 1.5, 0.75))
    sep = frame_cost(sj.technique("separable", taps=9), sc.buffers, mat, sc.camera)
    jim = frame_cost(sj.technique("jimenez", taps=17), sc.buffers, mat, sc.camera)
    assert (sep["samples"], sep["fetches"]) == (18, 34) and sep["rule"].startswith("2 passes x 9 taps")
    assert jim["samples"] == 34
    # and the pixels whose kernel reaches under min_footprint_px keep their local shading: no taps (every SSS pixel
    # was counted as computed; a material 64x narrower cost 38 fetches a pixel where the pass computed none)
    narrow = sj.BurleyMaterial((0.8, 0.6, 0.5), (3.0 / 64, 1.5 / 64, 0.75 / 64))
    skipped = frame_cost(sj.technique("separable", taps=9), sc.buffers, narrow, sc.camera)
    out = np.asarray(sj.separable(sc.buffers, narrow, sc.camera, taps=9))
    local = np.asarray(sc.buffers.irradiance) * np.asarray(sc.buffers.albedo)  # the demo's albedo pass
    sss = (np.asarray(sc.buffers.material_id) > 0) & np.isfinite(np.asarray(sc.buffers.depth))
    changed = float((np.abs(out - local).max(-1) > 1e-6)[sss].mean())
    assert skipped["active_fraction"] == pytest.approx(changed, abs=0.02) and skipped["active_fraction"] < 0.5


def test_the_commands_that_read_a_frame_describe_its_camera_and_channels_alike():
    # apply, fit --render, report and advise --frame read a frame's buffers the same way, so their camera and
    # channel flags must say the same thing: before, four copies had drifted apart (--depth-kind's meaning given by
    # apply only, --channel-map's buffers named by apply only)
    import argparse

    from sss_jax.cli import build_parser

    commands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
    flags = ("--focal-px", "--mm-per-unit", "--depth-kind", "--channel-map")
    described = {}
    for name in ("apply", "fit", "report", "advise"):
        actions = {s: a for a in commands[name]._actions for s in a.option_strings}
        described[name] = [(actions[f].help, actions[f].choices, actions[f].default, actions[f].type) for f in flags]
    assert all(d == described["apply"] for d in described.values()), described
    assert all(h for h, *_ in described["apply"])  # every flag explained
    assert "distance to the camera" in described["fit"][2][0] and "irradiance, depth" in described["report"][3][0]
