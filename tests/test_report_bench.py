"""The HTML report and the bench: every section and field present, everything embedded, goals beside ratios."""

import json
import pathlib
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from sss_jax._bench import GOALS, cost_per_pixel, run_bench, xla_plain_separable
from sss_jax._demo import demo_montecarlo, demo_trade, run_demo
from sss_jax._reporting import write_demo_report
from sss_jax.cli import main

# One frame size and one sample/tap count for the demo, the report and the bench (and `sss-jax demo` in
# tests/test_io_cli.py): the report's trade table (burley 8/32/64, separable 9/25) and the bench's error scene
# (48x64) and ratio passes (burley 32, separable 25) then reuse the passes compiled for the demo instead of compiling
# their own. The checks below are about structure and bounds that hold at any of these sizes.
DEMO_H, DEMO_W, DEMO_SAMPLES, DEMO_TAPS = 48, 64, 8, 9
PRESETS = pathlib.Path(__file__).resolve().parents[1] / "fits"


def test_demo_report_has_every_section_and_embeds_its_images(tmp_path):
    result = run_demo(height=DEMO_H, width=DEMO_W, samples=DEMO_SAMPLES, taps=DEMO_TAPS, repeats=1)
    # the trade at the demo's own counts (compiled already) and the largest ones the rows below name (burley 64,
    # separable 25) plus burley 32 (the bench's ratio pass): the table's structure needs no other count, and each
    # count left out is a compilation less
    trade = demo_trade(result, taps=(DEMO_TAPS, 25), samples=(DEMO_SAMPLES, 32, 64), repeats=1)
    montecarlo = demo_montecarlo(photons=4000)
    html_path = write_demo_report(result, tmp_path, trade=trade, montecarlo=montecarlo)
    page = html_path.read_text()
    for title in ("Summary", "Renders", "Against the reference", "Per material", "Speed against accuracy",
                  "Profiles and kernels", "Energy", "Presets", "Engines", "Transmission", "Inputs", "Machine"):
        assert f">{title}</h2>" in page, title
    assert len(re.findall(r"data:image/png;base64,", page)) >= 15
    assert not re.search(r"(src|href)=['\"](http|file:|/)", page)  # self-contained
    data = json.loads((tmp_path / "report.json").read_text())
    # the common schema, with the demo's own sections beside it
    assert set(data) == {"inputs", "material", "machine", "techniques", "sections", "flip", "local_shading", "notes"}
    # HDR-FLIP beside the other metrics in every row, its exposure range stated (the demo has no truth)
    assert all(0 <= r["vs_reference"]["flip_mean"] <= 1 for r in data["techniques"])
    assert [e["target"] for e in data["flip"]["exposures"]] == ["reference"] and data["flip"]["tonemapper"] == "ACES"
    rows = {(r["technique"], r["count"]): r for r in data["techniques"]}
    assert {("reference", None), ("burley", DEMO_SAMPLES), ("separable", DEMO_TAPS), ("sta", None),
            ("separable_two_gaussian", DEMO_TAPS), ("burley", 64), ("separable", 25)} <= set(rows)
    assert rows[("reference", None)]["vs_reference"]["rel_l2"] == 0 and all(r["vs_truth"] is None for r in rows.values())
    # the relative L2 the report states is the one the demo computed on its own (DemoResult.errors, same pixels)
    assert rows[("burley", DEMO_SAMPLES)]["vs_reference"]["rel_l2"] == pytest.approx(
        result.errors[f"burley_{DEMO_SAMPLES}"], rel=1e-6)
    mc = data["sections"]["Profiles and kernels"]["montecarlo_vs_burley"]
    assert [r["albedo"] for r in mc] == [0.5, 0.9, 0.99] and all(r["rel_l2_rR"] < 0.25 for r in mc)
    energy = {r["technique"]: r for r in data["sections"]["Energy"]["energy"]}
    assert energy["sta"]["R"] > 1 and energy["sta"]["conserves"].startswith("no")
    # transmission: every shipped preset compared, and for the index-matched ones (eta 1) the tabulated slab model
    # agrees with the preset's own Monte Carlo slabs far better than the closed form (docs/engines.md: table within
    # ~1% of Monte Carlo, the closed form 7-10% off), whatever the preset
    trans = data["sections"]["Transmission"]["transmission"]
    assert len(trans) == len(list(PRESETS.glob("*.json"))) - 1  # all but the schema
    matched = [r for r in trans if r["eta"] == 1.0]
    assert matched and all(r["slab vs MC"] < 0.02 < r["thin vs MC"] for r in matched)
    # Burley's error over samples x frames, split into bias and noise over seeds (issue #18)
    sampling = data["sections"]["Burley sampling: bias and noise"]["burley_sampling"]
    assert {(r["pattern"], r["frames"]) for r in sampling} == {("rotated", 1), ("rotated", 4), ("fixed", 1),
                                                               ("fixed", 4)}
    assert all(r["noise"] == 0 for r in sampling if (r["pattern"], r["frames"]) == ("fixed", 1))
    assert not list(tmp_path.glob(".*tmp*"))


def test_bench_reports_every_ratio_with_its_goal(bench_timed_together):
    # rows at the ratio resolution, which is also the error scene's (48x64): one shape for every pass. The burley row
    # uses 4 samples, a count nothing else compiles at this shape, so at least one compile time is measured (> 0).
    res = run_bench(repeats=1, grid=dict(taps=(DEMO_TAPS,), samples=(4,), resolutions=[(DEMO_W, DEMO_H)],
                                         ratio_resolution=(DEMO_W, DEMO_H)))
    assert set(res["ratios"]) == set(GOALS) == {"separable_vs_sepFilter2D", "separable_vs_xla_plain_separable",
                                                "burley_vs_filter2D", "coverage10_vs_full", "compile_seconds",
                                                "peak_memory_vs_input"}
    for name, r in res["ratios"].items():
        assert r["goal"] == f"{GOALS[name][0]} {GOALS[name][1]}"
        assert r["value"] is None or r["value"] > 0
    assert {"cv2.sepFilter2D_25", "cv2.filter2D_25x25", "scipy.fftconvolve_25x25"} == set(res["peers_ms"])
    # every ratio's two sides timed in turn in one run (a drift of the machine's speed falls on both): one after the
    # other, the 10% coverage once read 0.29 of the full frame where side by side it reads 0.11-0.13
    for sides in ({"burley", "cv2.filter2D_25x25"}, {"separable", "xla_plain"}, {"full", "10"}, {"three", "one"},
                  {"grey", "rgb"}, {"burley", "burley_nearest"}):
        assert any(sides <= names for names in bench_timed_together), sides
    techniques = {(r["technique"], r["count"]) for r in res["rows"]}
    assert techniques == {("sta", None), ("separable", DEMO_TAPS), ("burley", 4)}
    for r in res["rows"]:
        assert set(r["errors"]) == {"demo", "shadow_edge", "thin_line", "point_light"}
        assert r["ms_per_frame"] > 0
        assert set(r["cost_per_pixel"]) == {"fetches", "flops"} and r["cost_per_pixel"]["flops"] > 0
    # separable DEMO_TAPS taps, bilinear (its default): 2 passes x (2 pixels per tap off the centre + the centre)
    assert next(r for r in res["rows"] if r["technique"] == "separable")["cost_per_pixel"]["fetches"] == \
        2 * (2 * (DEMO_TAPS - 1) + 1)
    m = res["machine"]
    assert m["backend"] == jax.default_backend() and m["device"]
    assert m["impl"] in ("burley compacted, separable banded", "burley gather, separable banded")
    assert res["pareto"] and res["pareto"][0]["ms_per_frame"] == min(r["ms_per_frame"] for r in res["rows"])
    assert set(res["other_ratios"]) == {"separable_coverage10_vs_full", "burley_three_materials_vs_one",
                                        "burley_grey_vs_rgb", "xla_plain_separable_vs_sepFilter2D",
                                        "burley_nearest_vs_filter2D",
                                        "burley_nearest_vs_bilinear"}
    assert {(r["pattern"], r["samples"], r["frames"]) for r in res["burley_sampling"]} == {
        (p, n, k) for p in ("rotated", "fixed") for n in (8, 32) for k in (1, 4)}
    skips = res["footprint_skip"]
    assert [r["d_scale"] for r in skips] == [1 / 8, 1 / 32, 1 / 64]
    assert skips[0]["skipped_fraction"] < skips[-1]["skipped_fraction"]  # smaller d: more pixels under half a pixel
    for r in skips:
        assert 0 <= r["skipped_fraction"] <= 1 and r["rel_l2_with_skip"] >= 0 and r["rel_l2_without_skip"] >= 0


def test_xla_plain_separable_is_the_filter_sepfilter2d_runs():
    # the bench's compiler-floor peer must be the same filter as OpenCV's, or its ratio places nothing: equal away
    # from the border (OpenCV reflects there, the XLA filter pads with zeros)
    cv2 = pytest.importorskip("cv2")
    rng = np.random.default_rng(0)
    img = rng.uniform(0.0, 1.0, (40, 52, 3)).astype(np.float32)
    k = cv2.getGaussianKernel(25, 4.0).astype(np.float32)
    expected = cv2.sepFilter2D(img, -1, k, k)
    planar = jnp.asarray(np.moveaxis(img, -1, 0))
    got = np.moveaxis(np.asarray(xla_plain_separable(planar, jnp.asarray(k[:, 0]))), 0, -1)
    np.testing.assert_allclose(got[12:-12, 12:-12], expected[12:-12, 12:-12], rtol=1e-5, atol=1e-6)
    assert np.abs(got - expected)[:12].max() > 1e-3  # (the border does differ: the comparison is not vacuous)


def test_cost_per_pixel_counts_the_shaders_fetches():
    # texel fetches as Jimenez's and HDRP's shaders make them: separable 2 passes x the taps off the centre x (2 for
    # a linear fetch along the pass, 1 nearest) + the centre per pass (it was counted twice: as a tap too); Burley
    # samples x (4 bilinear, 1 nearest) + the centre
    assert cost_per_pixel("separable", 25, "linear")["fetches"] == 2 * (24 * 2 + 1)
    assert cost_per_pixel("separable", 25, "nearest")["fetches"] == 2 * (24 + 1)
    assert cost_per_pixel("burley", 32, "bilinear")["fetches"] == 32 * 4 + 1
    assert cost_per_pixel("burley", 32, "nearest")["fetches"] == 33
    # the arithmetic grows with the taps/samples and shrinks with point fetches
    assert cost_per_pixel("burley", 32, "nearest")["flops"] < cost_per_pixel("burley", 32, "bilinear")["flops"] < \
        cost_per_pixel("burley", 64, "bilinear")["flops"]
    assert cost_per_pixel("separable", 9, "linear")["flops"] < cost_per_pixel("separable", 25, "linear")["flops"]
    with pytest.raises(ValueError, match="no cost model for technique 'reference'"):
        cost_per_pixel("reference", None)


def test_bench_says_the_techniques_warnings_as_every_command_does(monkeypatch, capsys):
    # bench printed Python's raw form (the file, the line, the source line) where the other commands print
    # "sss-jax <command>: warning: <message>"
    import warnings

    import sss_jax._bench as bench
    from sss_jax._errors import SamplingWarning

    def run_bench(**kwargs):
        warnings.warn("separable: 9 taps leave tap cells wide", SamplingWarning, stacklevel=2)
        raise ValueError("stopped here")

    monkeypatch.setattr(bench, "run_bench", run_bench)
    assert main(["bench", "--quick", "--technique", "separable"]) == 2
    err = capsys.readouterr().err
    assert "sss-jax bench: warning: separable: 9 taps leave tap cells wide" in err and "warnings.warn" not in err


@pytest.mark.parametrize("flags, message", [(["--taps", "8"], "taps must be an odd positive integer"),
                                            (["--scale-levels", "-1"], "scale_levels must be"),
                                            (["--technique", "separable", "--taps", "8"], "taps must be an odd")])
def test_bench_refuses_a_bad_count_before_any_reference_runs(monkeypatch, capsys, flags, message):
    # `bench --taps 8` failed only after the reference images and the STA rows (~20 s): the runs' technique objects
    # are built (and checked) first
    import sss_jax._bench as bench

    def no_reference(*args, **kwargs):
        raise AssertionError("the reference ran before the options were checked")

    monkeypatch.setattr(bench, "reference", no_reference)
    assert main(["bench", "--quick", *flags]) == 2
    err = capsys.readouterr().err
    assert message in err and "reference images" not in err
