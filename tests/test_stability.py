"""The stability sweep (reduced) and its command line."""

import json

import pytest

from sss_jax._stability import run_sweep, sweep_cases
from sss_jax.cli import main


@pytest.fixture(scope="module")
def quick_sweep():
    return run_sweep(quick=True, progress=False)


def test_quick_sweep_has_no_nonfinite_outputs_or_gradients(quick_sweep):
    s = quick_sweep
    assert s["cases"] >= 500
    assert s["nonfinite_outputs"] == 0 and s["nonfinite_gradients"] == 0
    assert s["energy_unbounded"] == 0 and s["unexpected_errors"] == 0
    # limits of value: d -> 0 the identity, d -> large spreads the light (no return to the input), edges blur
    # monotonically with d, STA within its bound; each kind ran for every technique it applies to
    assert s["limit_violations"] == 0, [c for c in s["case_list"] if c["outcome"] == "limit_violated"]
    limits = [c for c in s["case_list"] if c["component"].startswith("limit_")]
    assert {(c["component"], c["params"].get("technique")) for c in limits} >= {
        (k, t) for k in ("limit_identity", "limit_large_d", "limit_monotone_edge")
        for t in ("burley", "separable_burley", "reference")}
    assert sum(c["component"] == "limit_sta_bounded" for c in limits) == 6
    assert s["ok"] + s["handled_errors"] == s["cases"]
    # every component took part, and both kinds of invalid input were caught with a message naming the input
    components = {c["component"] for c in s["case_list"]}
    assert {"burley", "separable_burley", "separable_two_gaussian", "reference", "sta", "profile",
            "kernel_preintegrated", "kernel_two_gaussian", "spiral_samples", "invalid_parameter",
            "montecarlo", "fit_two_gaussian", "fit_sta"} <= components
    messages = [c["message"] for c in s["case_list"] if c["outcome"] == "handled_error"]
    assert any("irradiance has" in m for m in messages)  # 1e30 in float16 is inf: caught, not propagated
    assert any("d_mm must" in m for m in messages) and any("albedo must" in m for m in messages)


def test_full_sweep_is_large_enough():
    cases = list(sweep_cases(quick=False))
    assert len(cases) >= 2000
    # the cross product covers every extreme the issue names
    tech = [c.params for c in cases if c.component == "burley"]
    assert {p["d_mm"] for p in tech} == {0.0, 1e-6, 1e-3, 1.0, 1e3, 1e6}
    assert {p["dtype"] for p in tech} == {"float16", "float32", "float64"}
    assert {tuple(p["size"]) for p in tech} == {(1, 1), (1, 5), (4, 4)}


def test_stability_cli_writes_json(tmp_path, monkeypatch, quick_sweep):
    import sss_jax._stability as stability

    monkeypatch.setattr(stability, "run_sweep", lambda quick, progress: quick_sweep)
    out = tmp_path / "s.json"
    assert main(["stability", "--quick", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    for key in ("cases", "handled_errors", "nonfinite_outputs", "nonfinite_gradients", "case_list"):
        assert key in data
    assert main(["stability", "--json", str(tmp_path / "missing" / "s.json")]) == 2


def test_stability_cli_prints_every_count_that_fails_it(tmp_path, monkeypatch, capsys, quick_sweep):
    # before, a violated limit made the exit status 1 while every count printed read 0 (limits were not printed)
    import sss_jax._stability as stability

    cases = [dict(c) for c in quick_sweep["case_list"]]
    bad = next(i for i, c in enumerate(cases) if c["component"] == "limit_identity")
    cases[bad] = dict(cases[bad], outcome="limit_violated", message="d -> 0 is not the identity (fake)")
    summary = dict(quick_sweep, ok=quick_sweep["ok"] - 1, limit_violations=1, case_list=cases)
    monkeypatch.setattr(stability, "run_sweep", lambda quick, progress: summary)
    assert main(["stability", "--quick", "--json", str(tmp_path / "s.json")]) == 1
    out = capsys.readouterr().out
    assert "limits violated:      1" in out and "limit_violated: limit_identity" in out and "(fake)" in out
