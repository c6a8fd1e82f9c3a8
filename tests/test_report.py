"""``sss-jax report`` / ``sj.report``: the layout's numbers against hand computations, the real Blender/Cycles frame
against an independent NumPy computation from the written images, the reference cache, and bad input."""

import json
import pathlib
import re

import numpy as np
import pytest

import sss_jax as sj
from sss_jax.cli import main

PRESETS = pathlib.Path(__file__).resolve().parents[1] / "fits"
BLENDER_INPUT = "reference/blender/irradiance_backlit.exr"
BLENDER_TRUTH = "reference/blender/burley_backlit.exr"
# The material of reference/blender/README.md: A = (0.85, 0.75, 0.55), radius (0.4, 0.25, 0.15) m and Cycles 3.x's
# d = radius / (4 pi): d = (31.83, 19.89, 11.94) mm. A small frame budget: three techniques at one count each, no
# repeated timing, a 3 px reference window (the report's numbers are checked, not the reference's accuracy).
BLENDER_ARGS = ["--albedo", "0.85,0.75,0.55", "--d-mm", "31.831,19.894,11.937", "--techniques", "sta,separable,burley",
                "--light-dir", "0.3,-0.4,0.9", "--taps", "9", "--samples", "8", "--radius-px", "3", "--repeats", "0",
                "--no-progress"]


def _frame(tmp, h=6, w=8):
    """A small ReportData by hand: reference r, one technique 1.1 r on the SSS pixels, a truth 0.8 r."""
    rng = np.random.default_rng(3)
    ref = rng.uniform(0.1, 0.9, (h, w, 3))
    ids = np.zeros((h, w), int)
    ids[:, 2:5] = 1
    ids[:, 5:] = 2
    out = np.where(ids[..., None] > 0, 1.1 * ref, ref)
    return ref, ids, out


def test_layout_numbers_match_hand_computation(tmp_path):
    ref, ids, out = _frame(tmp_path)
    truth = 0.8 * ref
    data = sj.ReportData(
        frames=(sj.FrameImages("f", shaded=ref, reference=ref, material_id=ids, truth=truth),),
        runs=(sj.TechniqueRun("separable", 9, 2.0, (out,)), sj.TechniqueRun("burley", 8, 5.0, (ref,)),
              sj.TechniqueRun("burley", 16, 1.0, (out,))),
        inputs=[{"name": "f"}], material={"albedo": [[1, 1, 1]]}, machine={"cpu": "test"})
    html = sj.report(data, tmp_path / "out").read_text()
    doc = json.loads((tmp_path / "out" / "report.json").read_text())
    # the issue's schema, and (issue #27) local shading as the floor with the notes that name who falls below it,
    # and (issue #30) HDR-FLIP's settings
    assert set(doc) == {"inputs", "material", "machine", "techniques", "local_shading", "notes", "flip"}
    rows = {(r["technique"], r["count"]): r for r in doc["techniques"]}
    assert set(rows) == {("separable", 9), ("burley", 8), ("burley", 16)}
    assert set(rows[("burley", 8)]) == {"technique", "count", "label", "options", "cost_per_pixel", "ms_per_frame",
                                        "vs_reference", "vs_truth", "worse_than_local_shading"}
    # local shading here is r itself: 0 against the reference, ||r - 0.8 r|| / ||0.8 r|| = 0.25 against the truth;
    # 1.1 r is worse on both (0.1 > 0, 0.375 > 0.25), r itself on neither (equal is not worse)
    assert doc["local_shading"]["vs_reference"]["rel_l2"] == 0.0
    assert doc["local_shading"]["vs_truth"]["rel_l2"] == pytest.approx(0.25, rel=1e-12)
    assert rows[("separable", 9)]["worse_than_local_shading"] == {"vs_reference": True, "vs_truth": True}
    assert rows[("burley", 8)]["worse_than_local_shading"] == {"vs_reference": False, "vs_truth": False}
    assert any(n.startswith("separable 9 does worse than local shading against the truth") for n in doc["notes"])
    assert not any(n.startswith("burley 8 ") for n in doc["notes"])
    assert "does worse than local shading" in html
    # ||1.1 r - r|| / ||r|| = 0.1 on the masked pixels; the identical image is 0 with no colour difference
    assert rows[("separable", 9)]["vs_reference"]["rel_l2"] == pytest.approx(0.1, rel=1e-12)
    assert rows[("burley", 8)]["vs_reference"] == {"rel_l2": 0.0, "delta_e_mean": 0.0, "delta_e_p95": 0.0,
                                                   "flip_mean": 0.0}
    # HDR-FLIP of 1.1 r against r, straight from flip-evaluator on the SSS pixels at the range the report states
    import flip_evaluator

    (rng_ref,) = [e for e in doc["flip"]["exposures"] if e["target"] == "reference"]
    params = {"startExposure": rng_ref["start"], "stopExposure": rng_ref["stop"], "numExposures": rng_ref["count"]}
    fmap, _, _ = flip_evaluator.evaluate(ref.astype(np.float32), out.astype(np.float32), "HDR", applyMagma=False,
                                         parameters=params)
    assert rows[("separable", 9)]["vs_reference"]["flip_mean"] == pytest.approx(fmap[..., 0][ids > 0].mean(), abs=1e-6)
    assert rows[("separable", 9)]["vs_reference"]["flip_mean"] > 0.01
    # against the truth 0.8 r: ||1.1 r - 0.8 r|| / ||0.8 r|| = 0.3 / 0.8, and ||r - 0.8 r|| / ||0.8 r|| = 0.25
    assert rows[("separable", 9)]["vs_truth"]["rel_l2"] == pytest.approx(0.375, rel=1e-12)
    assert rows[("burley", 8)]["vs_truth"]["rel_l2"] == pytest.approx(0.25, rel=1e-12)
    assert rows[("burley", 8)]["vs_truth"]["delta_e_mean"] > 0
    assert "data:image/png;base64," in html and not re.search(r"(src|href)=['\"](http|file:|/)", html)


def test_pareto_front_by_hand():
    # times and errors: (1, 0.5) fastest; (2, 0.1) better; (3, 0.2) dominated by (2, 0.1); (5, 0.05) best error;
    # (2, 0.1) twice: neither dominates the other; an untimed run is never on the front
    flags = sj._report.pareto_flags([1, 2, 3, 5, 2, None], [0.5, 0.1, 0.2, 0.05, 0.1, 0.0])
    assert flags == [True, True, False, True, True, False]


@pytest.mark.usefixtures("as_users_run_it")  # the library's own message for a malformed section
def test_extra_sections_are_placed_and_checked(tmp_path):
    ref, ids, out = _frame(tmp_path)
    data = sj.ReportData(frames=(sj.FrameImages("f", ref, ref, ids),), runs=(sj.TechniqueRun("burley", 8, 1.0, (out,)),),
                         inputs=[{}], material={}, machine={})
    html = sj.report(data, tmp_path / "a", extra_sections=[("Fit to the offline render", "<p id=fit>before/after</p>"),
                                                          ("With data", "<p>x</p>", {"k": [1, 2]})]).read_text()
    assert ">Fit to the offline render</h2><p id=fit>before/after</p>" in html
    assert html.index("Speed against accuracy</h2>") < html.index("Fit to the offline render</h2>")
    doc = json.loads((tmp_path / "a" / "report.json").read_text())
    assert doc["sections"] == {"With data": {"k": [1, 2]}} and doc["techniques"][0]["vs_truth"] is None
    with pytest.raises(ValueError, match=r"extra_sections\[0\] must be \(title, html_fragment\)"):
        sj.report(data, tmp_path / "b", extra_sections=["just a string"])
    assert not (tmp_path / "b").exists()
    with pytest.raises(ValueError, match="1 image\\(s\\) for 2 frame\\(s\\)"):
        sj.ReportData(frames=(data.frames[0], data.frames[0]), runs=data.runs, inputs=[], material={}, machine={})


def _read_rgb(path, names):
    """Independent reader (OpenImageIO directly): the named channels of every subimage, stacked."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    chans, sub = {}, 0
    while inp.seek_subimage(sub, 0):
        spec = inp.spec()
        px = np.asarray(inp.read_image(sub, 0, 0, spec.nchannels, oiio.FLOAT)).reshape(spec.height, spec.width, -1)
        chans.update({n: px[..., c] for c, n in enumerate(spec.channelnames)})
        sub += 1
    inp.close()
    return np.stack([chans[n] for n in names], axis=-1).astype(np.float64)


def test_blender_frame_report_against_cycles_truth(shared_dir, tmp_path, capsys):
    src, truth = shared_dir / BLENDER_INPUT, shared_dir / BLENDER_TRUTH
    out = tmp_path / "rep"
    assert main(["report", str(src), "--out", str(out), "--truth", str(truth), *BLENDER_ARGS]) == 0
    doc = json.loads((out / "report.json").read_text())
    assert set(doc) == {"inputs", "material", "machine", "techniques", "flip", "notes", "local_shading"}
    rows = {(r["technique"], r["count"]): r for r in doc["techniques"]}
    assert set(rows) == {("sta", None), ("separable", 9), ("burley", 8), ("reference", None)}
    # independent: Cycles' Combined and the SSS pixels (IndexOB > 0 on a surface; Blender's background depth is 1e10)
    # read straight from the EXRs, the technique's output from the image the report wrote, the issue's formula
    combined = _read_rgb(truth, [f"ViewLayer.Combined.{c}" for c in "RGB"])
    index_ob = _read_rgb(src, ["ViewLayer.IndexOB.X"])[..., 0]
    depth = _read_rgb(src, ["ViewLayer.Depth.Z"])[..., 0]
    mask = (index_ob > 0.5) & (depth < 1e9)
    assert mask.sum() > 30_000  # sphere and Suzanne (tests the mask is not vacuous)
    import flip_evaluator

    lum = np.maximum(combined[mask], 0) @ [0.2126, 0.7152, 0.0722]  # Rec. 709 luminance
    A, B, C = 0.36 * 2.51 - 0.85 * 0.36 * 2.43, 0.6 * 0.03 - 0.85 * 0.6 * 0.59, -0.85 * 0.14  # ACES fit = 0.85
    x = (-B + np.sqrt(B * B - 4 * A * C)) / (2 * A)
    start, stop = np.log2(x / lum.max()), np.log2(x / np.sort(lum)[lum.size // 2])
    params = {"startExposure": start, "stopExposure": stop, "numExposures": int(max(2, np.ceil(stop - start)))}
    (stated,) = [e for e in doc["flip"]["exposures"] if e["target"] == "truth"]
    assert (stated["start"], stated["stop"], stated["count"]) == pytest.approx(tuple(params.values()), abs=1e-9)
    for (tech, count), row in rows.items():
        img = _read_rgb(out / "images" / "irradiance_backlit" / (tech + ("" if count is None else f"_{count}") + ".exr"),
                        "RGB")
        expected = np.linalg.norm((img - combined)[mask]) / np.linalg.norm(combined[mask])
        assert row["vs_truth"]["rel_l2"] == pytest.approx(expected, rel=1e-6), tech
        # a real gap (back-lit ears, noise) but not a broken image; STA adds light, so it may exceed 1
        assert 0.05 < row["vs_truth"]["rel_l2"] < (5.0 if tech == "sta" else 1.0), tech
        # HDR-FLIP against the truth: flip-evaluator itself on the written image and Cycles' Combined, at the range
        # HDR-FLIP's rule gives on the truth's SSS pixels (log2(x / Y_max) to log2(x / Y_median), x = 0.85 under ACES)
        fmap, _, _ = flip_evaluator.evaluate(combined.astype(np.float32), np.maximum(img, 0).astype(np.float32), "HDR",
                                             applyMagma=False, parameters=params)
        assert row["vs_truth"]["flip_mean"] == pytest.approx(fmap[..., 0][mask].mean(), abs=1e-6), tech
        assert 0.0 < row["vs_truth"]["flip_mean"] < 1.0, tech
    assert rows[("reference", None)]["vs_reference"]["rel_l2"] == 0
    page = (out / "report.html").read_text()
    assert len(re.findall(r"data:image/png;base64,", page)) >= 12
    assert not re.search(r"(src|href)=['\"](http|file:|/)", page)  # self-contained
    assert "computed in" in page and "read from the cache" not in page
    assert len(list((out / "cache").glob("reference-*.npz"))) == 1

    # a second run (of one technique, to stay cheap) reads the reference back from the cache and states the same
    # numbers against the truth (STA's light and burley's samples left out with them: a flag of a technique that does
    # not run is refused)
    at, counts = BLENDER_ARGS.index("--light-dir"), BLENDER_ARGS.index("--samples")
    second = [a if a != "sta,separable,burley" else "separable"
              for a in BLENDER_ARGS[:at] + BLENDER_ARGS[at + 2:counts] + BLENDER_ARGS[counts + 2:]]
    assert main(["report", str(src), "--out", str(out), "--truth", str(truth), *second]) == 0
    again = json.loads((out / "report.json").read_text())
    assert "read from the cache" in (out / "report.html").read_text()
    ref_again = {(r["technique"], r["count"]): r for r in again["techniques"]}[("reference", None)]
    assert ref_again["vs_truth"] == rows[("reference", None)]["vs_truth"]
    assert not list(out.parent.glob(".rep.staging-*"))


def _tiny_exr(path, **extra):
    from sss_jax._io import write_exr

    h, w = 8, 10
    chans = {"R": np.full((h, w), 0.5), "G": np.full((h, w), 0.5), "B": np.full((h, w), 0.5),
             "Z": np.full((h, w), 2.0), "id": np.ones((h, w))}
    chans.update(extra)
    write_exr(path, chans, attributes={"sss_jax:focal_px": 100.0, "sss_jax:mm_per_unit": 10.0})
    return path


@pytest.mark.parametrize("case, message", [
    ("missing", "file not found"),
    ("truth_size", "truth is 5x4 but the input frame is 10x8"),
    ("truth_channels", r"truth channel\(s\) \['Combined.R'"),
    ("technique", "--techniques: unknown technique 'ssss'"),
    ("sta_light", "--techniques sta needs --light-dir"),
    ("material", "needs the material"),
    ("taps", "taps must be odd positive integers"),
    ("truth_count", "2 truth file\\(s\\) for 1 input frame\\(s\\)"),
])
def test_bad_input_clear_message_nonzero_nothing_written(tmp_path, capsys, case, message):
    frame = _tiny_exr(tmp_path / "in.exr")
    truth = tmp_path / "truth.exr"
    from sss_jax._io import write_exr

    write_exr(truth, np.zeros((4, 5, 3)) if case == "truth_size" else np.zeros((8, 10, 3)))
    out = tmp_path / "rep"
    args = {"missing": [str(tmp_path / "nope.exr")], "truth_size": [str(frame), "--truth", str(truth)],
            "truth_channels": [str(frame), "--truth", str(truth), "--truth-channels", "Combined"],
            "technique": [str(frame), "--techniques", "ssss"], "sta_light": [str(frame), "--techniques", "sta"],
            "material": [str(frame), "--albedo", "0.5"], "taps": [str(frame), "--taps", "8"],
            "truth_count": [str(frame), "--truth", str(truth), str(truth)]}[case]
    mat = [] if case == "material" else ["--d-mm", "1,1,1"]
    assert main(["report", *args, "--out", str(out), *mat, "--no-progress", "--repeats", "0"]) == 2
    err = capsys.readouterr().err
    assert re.search(message, err), err
    assert err.startswith("sss-jax report: ")
    assert not out.exists()  # nothing partial: not even the folder
    assert not list(tmp_path.glob(".rep.staging-*")) and not list(tmp_path.glob("sss-jax-report-*"))


def test_burley_options_are_checked_against_its_signature(tmp_path):
    frame = _tiny_exr(tmp_path / "in.exr")
    with pytest.raises(ValueError, match=r"burley_options \['no_such_option'\] not accepted"):
        sj.evaluate_frames([frame], sj.BurleyMaterial((0.8, 0.8, 0.8), (1.0, 1.0, 1.0)), techniques=["burley"],
                           burley_options={"no_such_option": 1})


def test_several_presets_through_the_id_channel(tmp_path):
    # two presets, ids 1 and 2: the material table has one row per preset in the order given, and the per-material
    # table of the page covers both ids; the separable takes the presets' two-Gaussian kernels
    ids = np.ones((8, 10))
    ids[:, 5:] = 2
    frame = _tiny_exr(tmp_path / "in.exr", id=ids)
    out = tmp_path / "rep"
    assert main(["report", str(frame), "--out", str(out), "--preset", "skin1,marble", "--techniques", "separable",
                 "--taps", "9", "--radius-px", "2", "--repeats", "0", "--no-progress", "--no-images"]) == 0
    doc = json.loads((out / "report.json").read_text())
    skin1 = json.loads((PRESETS / "skin1.json").read_text())
    marble = json.loads((PRESETS / "marble.json").read_text())
    np.testing.assert_allclose(doc["material"]["d_mm"], [skin1["burley"]["d_mm"], marble["burley"]["d_mm"]], rtol=1e-6)
    assert doc["material"]["names"] == ["skin1", "marble"] and doc["material"]["separable_kernel"] == "two-Gaussian"
    page = (out / "report.html").read_text()
    assert "<td>skin1</td>" in page and "<td>marble</td>" in page
    assert not (out / "images").exists()


def test_trade_figure_gives_every_technique_its_own_colour_and_a_legend():
    # issue #30: separable and separable_two_gaussian were drawn in the same colour
    from matplotlib.colors import to_rgba

    from sss_jax._report._plots import trade_figure

    names = ["sta", "separable", "separable_two_gaussian", "burley", "reference", "hdrp", "eevee-next", "jimenez"]
    rows = [{"technique": n, "count": 8, "ms_per_frame": 1.0 + i, "vs_reference": {"rel_l2": 0.1 / (i + 1)},
             "pareto_vs_reference": False} for i, n in enumerate(names)]
    fig = trade_figure(rows, [("vs_reference", "vs reference")])
    ax = fig.axes[0]
    colours = {c.get_label(): tuple(to_rgba(c.get_facecolor()[0])) for c in ax.collections}
    assert set(colours) == set(names)
    assert len(set(colours.values())) == len(names)  # no two techniques share a colour
    assert colours["reference"] == to_rgba("black")
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert set(names) <= set(legend)


def test_a_truth_of_two_view_layers_is_read_from_the_one_named(tmp_path):
    # an offline render with two layers (Blender's ViewLayer lit, ViewLayer.001 black): the truth's Combined of the
    # first in the file was taken silently; now the ambiguity is named with how to choose, and a pass's full name or
    # three channel names choose
    import OpenEXR

    from sss_jax._evaluate import read_truth
    from sss_jax._io import SSSInputError

    one = np.ones((4, 6), np.float32)
    ch = {}
    for layer, value in (("ViewLayer.001", 0.0), ("ViewLayer", 1.0)):
        ch.update({f"{layer}.Combined.{c}": value * one for c in "RGB"})
        ch[f"{layer}.Depth.Z"] = one
    with OpenEXR.File({"type": OpenEXR.scanlineimage}, ch) as f:
        f.write(str(tmp_path / "truth.exr"))
    with pytest.raises(SSSInputError, match=r"2 view layers hold the passes \('ViewLayer.001', 'ViewLayer'\); name its "
                                            r"channels \(--truth-channels ViewLayer.001.Combined.R,"):
        read_truth(tmp_path / "truth.exr")
    assert np.all(read_truth(tmp_path / "truth.exr", "ViewLayer.Combined") == 1.0)
    names = ",".join(f"ViewLayer.001.Combined.{c}" for c in "RGB")
    assert np.all(read_truth(tmp_path / "truth.exr", names) == 0.0)


def test_a_truth_whose_layers_hold_only_combined_is_never_mixed(tmp_path):
    # two layers with Combined and no Depth (a beauty render's layers): the first in the file was read silently
    # (the fuzz's dimmer ViewLayer.001 scored every technique against half the light); now named as ambiguous
    import OpenEXR

    from sss_jax._evaluate import read_truth
    from sss_jax._io import SSSInputError

    one = np.ones((4, 6), np.float32)
    ch = {f"{layer}.Combined.{c}": value * one for layer, value in (("ViewLayer.001", 0.5), ("ViewLayer", 1.0))
          for c in "RGB"}
    with OpenEXR.File({"type": OpenEXR.scanlineimage}, ch) as f:
        f.write(str(tmp_path / "truth.exr"))
    with pytest.raises(SSSInputError, match=r"2 view layers hold the passes"):
        read_truth(tmp_path / "truth.exr")
    assert np.all(read_truth(tmp_path / "truth.exr", "ViewLayer.Combined") == 1.0)


def test_a_truth_is_checked_against_the_frame_it_scores(tmp_path):
    # black on every SSS pixel: refused naming the truth (it was "reference is black on every masked pixel", after
    # the reference's computation); negative radiance: said; an overscan margin: the frame's pixels read from it
    import OpenEXR

    from sss_jax._evaluate import read_truth
    from sss_jax._io import SSSInputError, read_frame, write_exr

    frame = read_frame(_tiny_exr(tmp_path / "in.exr"))
    write_exr(tmp_path / "black.exr", np.zeros((8, 10, 3)))
    with pytest.raises(SSSInputError, match=r"black.exr: the truth is black on every SSS pixel of in.exr \(80 pixels\)"):
        read_truth(tmp_path / "black.exr", frame=frame)
    rgb = np.full((8, 10, 3), 0.25)
    rgb[2, 3] = -5.0
    write_exr(tmp_path / "negative.exr", rgb)
    with pytest.warns(UserWarning, match=r"negative.exr: 1 SSS pixel\(s\) of the truth are negative \(down to -5\)"):
        assert read_truth(tmp_path / "negative.exr", frame=frame)[2, 3, 0] == -5.0
    # the truth rendered with a 2-px overscan margin: data window (-2, -2)-(11, 9) over the display window 10x8
    wide = np.zeros((12, 14, 3), np.float32)
    wide[2:10, 2:12] = np.arange(80, dtype=np.float32).reshape(8, 10, 1) + 1
    header = {"type": OpenEXR.scanlineimage, "compression": OpenEXR.ZIP_COMPRESSION,
              "dataWindow": (np.array([-2, -2], np.int32), np.array([11, 9], np.int32)),
              "displayWindow": (np.array([0, 0], np.int32), np.array([9, 7], np.int32))}
    with OpenEXR.File(header, {c: np.ascontiguousarray(wide[..., i]) for i, c in enumerate("RGB")}) as f:
        f.write(str(tmp_path / "overscan.exr"))
    got = read_truth(tmp_path / "overscan.exr", frame=frame)
    assert got.shape == (8, 10, 3) and np.array_equal(got[..., 0], np.arange(80).reshape(8, 10) + 1)


def test_a_damaged_or_non_finite_reference_cache_is_computed_again(tmp_path):
    # a cut cache file raised zipfile.BadZipFile out of the report (a traceback); a NaN image was read back and
    # scored as "black"
    from sss_jax._evaluate import _cached_reference, _store_reference

    image = np.ones((4, 5, 3), np.float32)
    _store_reference(tmp_path, "k", image, 1.5)
    assert _cached_reference(tmp_path, "k", (4, 5))[1] == 1.5
    path = tmp_path / "reference-k.npz"
    path.write_bytes(path.read_bytes()[:100])
    assert _cached_reference(tmp_path, "k", (4, 5)) is None
    _store_reference(tmp_path, "k", np.full((4, 5, 3), np.nan, np.float32), 1.5)
    assert _cached_reference(tmp_path, "k", (4, 5)) is None


def test_an_out_folder_that_cannot_be_written_is_refused_before_any_work(tmp_path, capsys):
    frame = _tiny_exr(tmp_path / "in.exr")
    (tmp_path / "a_file").write_text("mine")
    args = [str(frame), "--d-mm", "1,1,1", "--no-progress", "--repeats", "0"]
    assert main(["report", *args, "--out", str(tmp_path / "a_file" / "sub")]) == 2
    assert "a_file is a file, not a directory" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # "" would be the current folder
        main(["report", *args, "--out", ""])
    assert "argument --out: empty" in capsys.readouterr().err


def test_a_report_folder_shows_its_latest_report_and_a_users_json_is_kept(tmp_path, capsys):
    # a second report into the same folder left the first one's images beside its own (report.json listed only
    # the second's runs); a folder holding the user's own report.json had it replaced without a word
    frame = _tiny_exr(tmp_path / "in.exr")
    base = [str(frame), "--d-mm", "1,1,1", "--no-progress", "--repeats", "0", "--techniques", "separable"]
    out = tmp_path / "rep"
    assert main(["report", *base, "--taps", "9", "--out", str(out)]) == 0
    (out / "images" / "in" / "notes.txt").write_text("mine")  # not a report's: stays
    assert main(["report", *base, "--taps", "17", "--out", str(out)]) == 0
    names = sorted(p.name for p in (out / "images" / "in").iterdir())
    assert "separable_9.exr" not in names and "separable_17.exr" in names and "notes.txt" in names
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "report.json").write_text('{"my": "notes"}')
    capsys.readouterr()
    assert main(["report", *base, "--taps", "9", "--out", str(mine)]) == 2
    assert "holds a report.json that is not an sss-jax report" in capsys.readouterr().err
    assert (mine / "report.json").read_text() == '{"my": "notes"}'


def test_a_run_given_twice_is_refused_before_any_frame_is_computed(tmp_path, monkeypatch):
    # it was found after the reference and every run had been computed (20 s on the fuzz's 96x64 crop)
    import sss_jax._techniques as techniques

    frame = _tiny_exr(tmp_path / "in.exr")

    def computed(*args, **kwargs):
        raise AssertionError("a frame was computed first")

    monkeypatch.setattr(techniques, "reference_radius_px", computed)
    with pytest.raises(sj.SSSInputError, match=r"given twice \(--techniques, --taps or --samples\): separable 9"):
        sj.evaluate_frames([frame], sj.BurleyMaterial((0.8,) * 3, (1.0,) * 3), techniques=["separable", "separable"],
                           taps=(9,), radius_px=None, repeats=0, progress=False)
    with pytest.raises(sj.SSSInputError, match=r"an input frame is given twice: .*in.exr"):
        sj.evaluate_frames([frame, frame], sj.BurleyMaterial((0.8,) * 3, (1.0,) * 3), techniques=["separable"],
                           progress=False)


def test_a_report_of_an_overscan_frame_writes_its_images_with_the_frames_windows(tmp_path):
    # the report's images of a frame rendered with an overscan margin (data window (-2, -1)-(11, 8) over the
    # display window 10x8) were written at (0, 0) with a display window of the data's size: shifted by the margin
    # over the input in a compositor (the batch's outputs kept both windows)
    from sss_jax._io import write_exr

    h, w = 10, 14
    chans = {"R": np.full((h, w), 0.5), "G": np.full((h, w), 0.5), "B": np.full((h, w), 0.5),
             "Z": np.full((h, w), 2.0), "id": np.ones((h, w))}
    window = sj._io.Window(-2, -1, (0, 0, 10, 8))
    write_exr(tmp_path / "in.exr", chans, attributes={"sss_jax:focal_px": 100.0, "sss_jax:mm_per_unit": 10.0},
              window=window)
    assert main(["report", str(tmp_path / "in.exr"), "--d-mm", "1,1,1", "--no-progress", "--repeats", "0",
                 "--techniques", "separable", "--taps", "9", "--out", str(tmp_path / "rep")]) == 0
    images = sorted((tmp_path / "rep" / "images" / "in").glob("*.exr"))
    assert images
    for path in images:  # the reference and the technique
        frame = sj._io.read_frame(path, channel_map={"irradiance": ["R", "G", "B"], "depth": "R"})
        assert frame.window == window and frame.depth.shape == (h, w), path


def test_a_report_never_writes_over_its_own_inputs(tmp_path, capsys):
    # an earlier report's image given as the truth of a report into the same folder was replaced by this report's
    # image of that name (the inputs' files were not checked against the report's)
    frame = _tiny_exr(tmp_path / "in.exr")
    out = tmp_path / "rep"
    args = ["--preset", "skin1", "--techniques", "separable", "--taps", "9", "--radius-px", "2", "--repeats", "0",
            "--no-progress"]
    assert main(["report", str(frame), "--out", str(out), *args]) == 0
    earlier = sorted((out / "images" / "in").glob("*.exr"))
    assert earlier
    truth = earlier[0]
    before = truth.read_bytes()
    capsys.readouterr()
    # refused before any work: the same name would be replaced, another removed as an earlier report's stale image
    assert main(["report", str(frame), "--out", str(out), "--truth", str(truth), *args]) == 2
    assert f"{truth} lies in {out / 'images'}, which this report fills and clears" in capsys.readouterr().err
    assert truth.read_bytes() == before
    # the report's own check, where the API writes it
    from sss_jax._report._layout import _write

    with pytest.raises(sj.SSSInputError, match="lies in"):
        _write(out, {"inputs": [{"path": str(frame), "truth": str(truth)}]}, "", [], [])
    assert truth.read_bytes() == before
