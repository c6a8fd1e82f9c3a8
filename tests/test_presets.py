"""The presets in fits/: complete, valid against the schema, derived as documented, reproducible, within their bounds."""

import csv
import json
import math
import pathlib
import shutil

import jsonschema
import numpy as np
import pytest

import sss_jax as sj
from sss_jax import _fit_presets as FP
from sss_jax._fit_presets._files import _markdown_table
from sss_jax._fit_presets._references import _r_max_mfp
from sss_jax import _io, _montecarlo, _presets
from sss_jax.cli import main as cli

FITS = pathlib.Path(__file__).resolve().parents[1] / "fits"
ARTIST = ["jade", "marble_artist", "milk", "skin", "wax"]


def _all_presets() -> dict[str, dict]:
    return {p.stem: json.loads(p.read_text()) for p in sorted(FITS.glob("*.json")) if p.stem != "schema"}


def _measured_rows(shared_dir) -> dict[str, dict[str, float]]:
    text = (shared_dir / "reference" / "measured_materials.csv").read_text()
    rows = csv.DictReader(line for line in text.splitlines() if line.strip() and not line.startswith("#"))
    return {r["name"]: {k: float(v) for k, v in r.items() if k != "name"} for r in rows}


def _without_seconds(x):
    # timings differ run to run; iteration counts may differ across CPUs (another rounding of the last bits sends
    # Levenberg-Marquardt down another path to the same optimum), which the parameters' tolerance below checks
    if isinstance(x, dict):
        return {k: _without_seconds(v) for k, v in x.items() if k not in ("seconds", "iterations")}
    if isinstance(x, list):
        return [_without_seconds(v) for v in x]
    return x


def test_every_material_has_a_preset_and_every_preset_validates(shared_dir):
    schema = json.loads((FITS / "schema.json").read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    # the schema in fits/ is the one the package ships
    assert schema == json.loads((pathlib.Path(sj.__file__).parent / "data" / "preset.schema.json").read_text())
    presets = _all_presets()
    assert set(presets) == set(_measured_rows(shared_dir)) | set(ARTIST)
    validator = jsonschema.Draft202012Validator(schema)
    for name, p in presets.items():
        errors = sorted(validator.iter_errors(p), key=str)
        assert not errors, f"{name}.json: {errors[0].message} at {list(errors[0].absolute_path)}"
        assert p["name"] == name and p["version"] == sj.__version__
        assert (FITS / p["montecarlo"]["cache"]).exists() and (FITS / "plots" / f"{name}.png").exists()
        # it loads as the techniques take it
        preset = _presets.load_preset(FITS / f"{name}.json")
        assert preset.two_gaussian is not None and preset.sta is not None
    # the schema rejects what it should (a preset without the two-Gaussian kernel; a weight above 1)
    bad = json.loads(json.dumps(presets["skin"]))
    del bad["separable"]["two_gaussian"]
    assert not validator.is_valid(bad)
    bad = json.loads(json.dumps(presets["skin"]))
    bad["separable"]["two_gaussian"]["w"][0] = 1.5
    assert not validator.is_valid(bad)


def test_measured_presets_follow_the_documented_derivation(shared_dir):
    # by hand from the table (Jensen et al. 2001, Table 2): l = 1/(s' + a), alpha' = s'/(s' + a); the searchlight
    # start d0 = l / (1.85 - A + 7|A - 0.8|^3) with A the preset's Monte Carlo reflectance (Christensen & Burley 2015,
    # Eq. 6); d itself the least-squares fit of r R(r) to the Monte Carlo profile
    for name, row in _measured_rows(shared_dir).items():
        p = json.loads((FITS / f"{name}.json").read_text())
        s = np.array([row[f"sigma_s_prime_{c}"] for c in "rgb"])
        a = np.array([row[f"sigma_a_{c}"] for c in "rgb"])
        l = 1 / (s + a)
        np.testing.assert_allclose(p["source"]["medium"]["mean_free_path_mm"], l, rtol=1e-12)
        np.testing.assert_allclose(p["source"]["medium"]["single_scattering_albedo"], s / (s + a), rtol=1e-12)
        assert p["source"]["medium"]["eta"] == 1.3
        A = np.array(p["albedo"])
        np.testing.assert_allclose(A, p["errors"]["albedo"]["montecarlo"], rtol=0)
        np.testing.assert_allclose(p["burley"]["d_searchlight_mm"], l / (1.85 - A + 7 * np.abs(A - 0.8) ** 3),
                                   rtol=1e-12)
        # A rises with the single-scattering albedo (channels that differ in it; spectralon's are all 1)
        alpha = s / (s + a)
        for i in range(3):
            for j in range(3):
                if alpha[i] < alpha[j] - 1e-3:
                    assert A[i] < A[j], (name, i, j)
        # the fitted d is a least-squares minimum of the documented objective, recomputed here from the cached run
        # (unit-energy profiles: R_mc = R / (l^2 A) per mm^2; Burley's R(r) = (e^{-r/d} + e^{-r/3d}) / (8 pi d r))
        cache = json.loads((FITS / p["montecarlo"]["cache"]).read_text())
        for c in range(3):
            prof = cache["profiles"][c]
            r = np.asarray(prof["profile"]["r_mfp"]) * l[c]
            rR_mc = np.asarray(prof["profile"]["rR"]) / l[c] / prof["total_reflectance"]

            def err(d, r=r, rR_mc=rR_mc):
                rR_b = (np.exp(-r / d) + np.exp(-r / (3 * d))) / (8 * np.pi * d)
                return np.linalg.norm(rR_b - rR_mc) / np.linalg.norm(rR_mc)

            d = p["burley"]["d_mm"][c]
            assert err(d) == pytest.approx(p["errors"]["profile"]["burley_vs_montecarlo"][c], rel=1e-6)
            assert err(d) <= min(err(0.98 * d), err(1.02 * d)), (name, c)
            assert err(d) < err(p["burley"]["d_searchlight_mm"][c]) + 1e-12


def test_h_function_against_chandrasekhar_table():
    # Chandrasekhar, Radiative Transfer (1960), Table XI (isotropic, conservative scattering):
    # H(1) = 2.9078, H(0.5) = 2.0128, H(0.1) = 1.2474
    np.testing.assert_allclose(FP.chandrasekhar_h(1.0, [1.0, 0.5, 0.1]), [2.9078, 2.0128, 1.2474], atol=2e-4)
    # alpha = 0: H = 1 (no scattering)
    np.testing.assert_allclose(FP.chandrasekhar_h(0.0, [0.3, 1.0]), 1.0)
    # his moment identity int_0^1 H dmu = (2/a)(1 - sqrt(1 - a)) at a < 1 (Eq. V.(29))
    x, w = np.polynomial.legendre.leggauss(64)
    for a in (0.3, 0.95):
        np.testing.assert_allclose(np.sum(0.5 * w * FP.chandrasekhar_h(a, 0.5 * (x + 1))),
                                   2 / a * (1 - math.sqrt(1 - a)), rtol=1e-8)
    for A in (0.05, 0.5, 0.85, 0.99):
        alpha = FP.albedo_from_surface_albedo(A)
        assert abs(1 - FP.chandrasekhar_h(alpha, 1.0)[0] * math.sqrt(1 - alpha) - A) < 1e-9


def test_artist_presets_reflect_their_albedo_in_monte_carlo():
    # the inversion through the H-function, checked by a random walk that no line of it produced: the Monte Carlo
    # total reflectance of the derived medium (eta 1) must be the artist's A within its statistical error
    for name in ARTIST:
        p = json.loads((FITS / f"{name}.json").read_text())
        A = np.array(p["source"]["albedo"])
        mc = np.array(p["errors"]["albedo"]["montecarlo"])
        se = np.array(p["errors"]["albedo"]["montecarlo_stderr"])
        assert np.all(np.abs(mc - A) < 4 * se + 1e-4), (name, mc, A, se)
        np.testing.assert_allclose(p["burley"]["d_mm"], p["source"]["d_mm"], rtol=1e-12)


def test_preset_errors_are_within_their_stated_bounds():
    # Image space (the error Jimenez et al. optimised): the 25-tap two-Gaussian separable pass against the dense
    # reference of the Burley profile and of the Monte Carlo profile, five test patterns, widest d = 2 px.
    # Bound 0.12 (measured 0.041-0.064 against Burley, 0.045-0.063 against Monte Carlo over the 17 presets with the
    # kernels fitted as rendered; 0.068-0.082 and 0.070-0.092 with the r-weighted fit before issue #18), the bound
    # of the fitted kernel in tests/test_fitting.py, for the same reason: the point light dominates (a delta shows
    # the kernel itself, and no separable product of Gaussians matches the radial 1/r peak), while local shading (no
    # scattering) is several times worse, as a broken fit would be.
    for name, p in _all_presets().items():
        e = p["errors"]
        assert e["image"]["two_gaussian_vs_burley"] < 0.12, name
        assert e["image"]["two_gaussian_vs_montecarlo"] < 0.12, name
        assert e["image"]["local_shading_vs_burley"] > 3 * e["image"]["two_gaussian_vs_burley"], name
        bound = 0.15 if p["source"]["kind"] == "artist" else 0.2
        assert max(e["profile"]["burley_vs_montecarlo"]) < bound, name
        # every fit says how it went
        for model in ("two_gaussian", "two_gaussian_montecarlo", "sta"):
            rec = p["fit"][model]
            assert rec["outcome"] == "successful" and rec["seconds"] > 0, (name, model, rec["outcome"])


def _burley_pixel_masses(d: float, pixel: float, half: int) -> np.ndarray:
    """Burley's normalised R(r) = (e^{-r/d} + e^{-r/(3d)}) / (8 pi d r) (Christensen & Burley 2015; the comparison
    paper's Eq. 4) integrated over the pixels of a (2 half + 1)^2 grid of side ``pixel`` centred on the origin:
    16x16 midpoints per pixel, and the centre pixel, which holds the 1/r peak, in polar form through the CDF
    1 - e^{-r/d}/4 - 3 e^{-r/(3d)}/4: 8 wedges, int_0^{pi/4} CDF(pixel / (2 cos t)) dt / (2 pi) each."""
    sub = 16
    offs = (np.arange(sub) + 0.5) / sub - 0.5
    xs = (np.arange(-half, half + 1)[:, None] + offs[None, :]).reshape(-1) * pixel
    r = np.hypot(xs[:, None], xs[None, :])
    n = 2 * half + 1
    R = (np.exp(-r / d) + np.exp(-r / (3 * d))) / (8 * math.pi * d * r)
    mass = R.reshape(n, sub, n, sub).mean(axis=(1, 3)) * pixel**2
    t, wt = np.polynomial.legendre.leggauss(48)
    t, wt = (t + 1) * math.pi / 8, wt * math.pi / 8
    edge = 0.5 * pixel / np.cos(t)
    cdf = 1 - np.exp(-edge / d) / 4 - 3 * np.exp(-edge / (3 * d)) / 4
    mass[half, half] = 8 * np.sum(wt * cdf) / (2 * math.pi)
    return mass


def _rendered_two_gaussian(w: float, sigma_near: float, sigma_far: float, pixel: float, half: int) -> np.ndarray:
    """What separable renders around a point: the outer product a(x) a(y) of the 1D kernel
    a(x) = w N(x; 0, sigma_near) + (1 - w) N(x; 0, sigma_far), integrated exactly over each pixel (normal CDFs)."""
    from scipy.special import ndtr

    edges = (np.arange(-half, half + 2) - 0.5) * pixel
    a = w * np.diff(ndtr(edges / sigma_near)) + (1 - w) * np.diff(ndtr(edges / sigma_far))
    return a[:, None] * a[None, :]


def test_rendered_two_gaussian_is_within_a_quarter_of_burley():
    # issue #18's bar, recomputed here from each file alone: the stored kernel as the separable pass renders it,
    # a(x) a(y), against Burley's 2D profile, both integrated over pixels of side d (+-d/2 about each centre; each
    # channel's d) on 41 x 41 pixels (+-20 d hold 99.9% of Burley's energy), relative L2 <= 0.25 in every channel of
    # every preset (measured 0.196: every Burley channel has the same shape). The kernel fitted before (w 0.628,
    # sigma 0.904 d / 3.07 d, radial and r-weighted) was 0.554 on this measure, so the test can fail.
    half = 20
    for name, p in _all_presets().items():
        tg = p["separable"]["two_gaussian"]
        stored = p["errors"]["kernel"]["pixel_d"]
        assert stored["pixel_side_over_d"] == 1.0
        for c, d in enumerate(p["burley"]["d_mm"]):
            target = _burley_pixel_masses(d, d, half)
            rendered = _rendered_two_gaussian(tg["w"][c], tg["sigma_near_mm"][c], tg["sigma_far_mm"][c], d, half)
            err = np.linalg.norm(rendered - target) / np.linalg.norm(target)
            assert err <= 0.25, (name, c, err)
            # the file says the same (its own integration: 8x8 midpoints)
            assert stored["two_gaussian_vs_burley"]["rendered_product"][c] == pytest.approx(err, abs=3e-3), (name, c)
            # the kernel fitted to Monte Carlo, rendered, against Monte Carlo: stated in the file, and a fit (no worse
            # than the Burley kernel rendered against Monte Carlo, up to the solver's tolerance)
            mc = stored["two_gaussian_montecarlo_vs_montecarlo"]["rendered_product"][c]
            assert mc <= stored["two_gaussian_vs_montecarlo"]["rendered_product"][c] + 1e-6, (name, c)
    # the old kernel on the same measure, from the issue: 0.54 (here 0.554)
    old = _rendered_two_gaussian(0.628, 0.904, 3.07, 1.0, half)
    target = _burley_pixel_masses(1.0, 1.0, half)
    assert np.linalg.norm(old - target) / np.linalg.norm(target) > 0.5


def test_spectralon_reflects_all_that_enters():
    # spectralon has no absorption (Jensen et al. 2001, Table 2): behind its eta 1.3 face the half-space returns
    # everything that enters, 1 - ((1.3 - 1)/(1.3 + 1))^2 = 0.98299 (Fresnel at normal incidence); issue #18 found
    # 0.975, the 0.8% that the Monte Carlo's event cap dropped
    p = _all_presets()["spectralon"]
    np.testing.assert_allclose(p["albedo"], 1 - (0.3 / 2.3) ** 2, atol=1e-5)
    assert max(p["errors"]["albedo"]["capped_weight"]) == 0.0


def test_exported_taps_are_the_kernel(tmp_path):
    p = json.loads((FITS / "skin.json").read_text())
    tg = p["separable"]["two_gaussian"]
    ex = p["separable"]["export"]
    k = sj.two_gaussian_kernel(tg["w"], tg["sigma_near_mm"], tg["sigma_far_mm"], taps=ex["taps"])
    np.testing.assert_allclose(ex["weights"], np.asarray(k.weights), rtol=1e-12)
    np.testing.assert_allclose(np.sum(ex["weights"], axis=0), 1.0, rtol=1e-12)  # energy conserving (Eq. 2)
    assert ex["hlsl"].count("float4(") == ex["taps"] and ex["glsl"].count("vec4(") == ex["taps"]
    # the HLSL rows parse back to the weights and offsets (8 decimals)
    rows = [r.split("float4(")[1].rstrip("),").split(",") for r in ex["hlsl"].splitlines() if "float4(" in r]
    vals = np.array([[float(v) for v in r] for r in rows])
    np.testing.assert_allclose(vals[:, :3], ex["weights"], atol=1e-8)
    np.testing.assert_allclose(vals[:, 3], ex["offsets_mm"], atol=1e-8)


def test_rerunning_reproduces_a_preset_and_its_monte_carlo(tmp_path):
    # the Monte Carlo cache: simulating again from its provenance gives the same tallies (one channel, the cheapest)
    cached = json.loads((FITS / "montecarlo" / "ketchup.json").read_text())
    prov = cached["provenance"]
    blue = cached["profiles"][2]
    again = _montecarlo.simulate(prov["single_scattering_albedo"][2], photons=prov["photons"], eta=prov["eta"],
                                    seed=prov["seed"] + 2, r_max_mfp=_r_max_mfp(prov["single_scattering_albedo"][2]),
                                    bins=len(blue["profile"]["r_mfp"]))
    np.testing.assert_allclose(again.total_reflectance, blue["total_reflectance"], rtol=1e-12)
    np.testing.assert_allclose((again.r_mfp * again.R), blue["profile"]["rR"], rtol=1e-9, atol=1e-15)
    # the whole preset from the cache: every number but the timings
    # (from a copy: a run that finds its cache stale writes it again, and the checkout's cache must stay as committed)
    cache = tmp_path / "montecarlo"
    cache.mkdir()
    shutil.copy(FITS / "montecarlo" / "ketchup.json", cache / "ketchup.json")
    fresh = FP.fit_preset("ketchup", photons=prov["photons"], seed=prov["seed"], cache_dir=cache)
    assert (cache / "ketchup.json").read_bytes() == (FITS / "montecarlo" / "ketchup.json").read_bytes()  # it was used
    stored = json.loads((FITS / "ketchup.json").read_text())
    a, b = _without_seconds(json.loads(json.dumps(fresh))), _without_seconds(stored)
    assert a.keys() == b.keys()
    _assert_close(a, b, "ketchup")


def _assert_close(a, b, where):
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _assert_close(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_close(x, y, f"{where}[{i}]")
    elif isinstance(a, float):
        # the engines' rendered fits (``rendered_fit`` blocks, the ``*-refit`` errors) are least-squares fits with
        # finite-difference Jacobians (diff_step 1e-4) through sampled passes (HDRP's nearest fetches, EEVEE Next's
        # TAA): their steps follow the float rounding of the CPU's vector code, so another CPU lands elsewhere on a
        # flat minimum (ketchup recomputed on an AMD EPYC against the preset written on an Intel Xeon, 2026-12-02:
        # HDRP medium's d 1.2-1.8% apart, its fitted error 0.1-7.9% apart with the same mean over the channels,
        # 0.2533 and 0.2530; EEVEE Next and Jimenez within 6e-4); the same CPU reproduces them exactly
        refit = "rendered_fit" in where or "-refit" in where
        assert math.isclose(a, b, rel_tol=0.1 if refit else 1e-5, abs_tol=1e-9), (where, a, b)
    elif isinstance(a, str) and where.endswith(("hlsl", "glsl")):
        assert a.splitlines()[0] == b.splitlines()[0], where  # digits beyond 1e-6 may differ across CPUs
    elif isinstance(a, str) and "rendered_fit" in where and where.endswith("(inspector hex)"):
        # a rendered fit's colour as the inspector's 8-bit hex (see above): each byte within 4 steps
        assert len(a) == len(b) == 7 and all(abs(int(a[i:i + 2], 16) - int(b[i:i + 2], 16)) <= 4
                                             for i in (1, 3, 5)), (where, a, b)
    else:
        assert a == b, where


def test_fit_command_writes_a_new_artist_preset(tmp_path, capsys):
    out = tmp_path / "fits"
    rc = cli(["fit", "--name", "test_wax", "--albedo", "0.9,0.7,0.5", "--d-mm", "3,2,1.2", "--out", str(out),
              "--photons", "3000", "--no-plots"])
    assert rc == 0, capsys.readouterr().err
    p = json.loads((out / "test_wax.json").read_text())
    jsonschema.validate(p, json.loads((out / "schema.json").read_text()))
    assert "test_wax" in (out / "README.md").read_text()
    np.testing.assert_allclose(p["burley"]["d_mm"], [3, 2, 1.2])
    assert p["montecarlo"]["photons"] == 3000 and (out / "montecarlo" / "test_wax.json").exists()
    # the preset drives a technique as any other
    preset = _presets.load_preset(out / "test_wax.json")
    np.testing.assert_allclose(np.asarray(preset.burley.d_mm)[0], [3, 2, 1.2])


@pytest.mark.parametrize("argv, message", [
    (["--name", "x", "--albedo", "0.5,0.5,0.5"], "needs all of --name, --albedo R,G,B and --d-mm R,G,B"),
    (["--name", "skin", "--albedo", "0.5,0.5,0.5", "--d-mm", "1,1,1"], "'skin' is a built-in material"),
    (["--name", "x", "--albedo", "1.5,0.5,0.5", "--d-mm", "1,1,1", "--photons", "20"], r"x: albedo must be 3 values in \(0, 1\)"),
    (["--name", "x", "--albedo", "0.5,0.5,0.5", "--d-mm", "1,0,1", "--photons", "20"], r"x: d_mm must be 3 values in \(0, 10000\] mm"),
    # an albedo of 0 wrote a preset whose engine errors were -1.5e17 (a ratio to a black reference); a d of 1e30
    # failed after the Monte Carlo with "Residuals are not finite in the initial point"
    (["--name", "x", "--albedo", "0,0,0", "--d-mm", "1,1,1", "--photons", "20"], r"x: albedo must be 3 values in \(0, 1\)"),
    (["--name", "x", "--albedo", "0.5,0.5,0.5", "--d-mm", "1e30,1,1", "--photons", "20"], r"x: d_mm must be 3 values in"),
    (["--material", "skin", "--photons", "0"], "--photons must be a positive integer"),
    (["--material", "skin", "--seed", "-1"], r"--seed must be an integer in \[0, 2\*\*32\), got -1"),
    (["--material", "skin", "--taps", "0"], "--taps must be a positive integer"),
    # checked before any work (before: --taps 4 failed each material after its Monte Carlo, --photons 5 said
    # "got 0", a preset named schema was overwritten by the schema, a/b failed after its Monte Carlo was written)
    (["--material", "skin", "--taps", "4"], "--taps must be odd"),
    (["--material", "skin", "--photons", "5"], "--photons must be at least 20"),
    # 10 passed the check and failed each material after its first walks: the medium's slabs ran one photon
    (["--material", "skin", "--photons", "10"], r"--photons must be at least 20 \(the medium's slabs run a tenth"),
    (["--name", "schema", "--albedo", "0.5,0.5,0.5", "--d-mm", "1,1,1"], "'schema' is reserved"),
    (["--name", "a/b", "--albedo", "0.5,0.5,0.5", "--d-mm", "1,1,1"], "preset name 'a/b': use letters"),
    (["--name", "../x", "--albedo", "0.5,0.5,0.5", "--d-mm", "1,1,1"], r"preset name '\.\./x'"),
    (["--name", ".hidden", "--albedo", "0.5,0.5,0.5", "--d-mm", "1,1,1"], "preset name '.hidden'"),
])
def test_fit_command_rejects_bad_input(tmp_path, capsys, argv, message):
    import re

    rc = cli(["fit", *argv, "--out", str(tmp_path / "o"), "--no-plots"])
    err = capsys.readouterr().err
    assert rc != 0 and re.search(message, err), err
    assert not list((tmp_path / "o").glob("*.json")) or rc == 1  # nothing half-written as a preset


def test_a_fitted_preset_that_would_not_load_is_not_written(tmp_path, monkeypatch):
    # a fit whose preset load_preset refuses (too few photons left the medium's transmission unresolved) fails that
    # material and leaves the preset already there; before, it was written and then broke the folder's README and
    # every load
    from sss_jax._fit_presets import _pipeline

    out = tmp_path / "fits"
    out.mkdir()
    good = json.loads(_presets._resolve("skin1").read_text())
    (out / "wax.json").write_text(json.dumps(good))
    tr = good["transmittance"]
    broken = dict(good, transmittance=dict(tr, resolved=[[True] + [False] * (len(row) - 1) for row in tr["resolved"]]))
    monkeypatch.setattr(_pipeline, "fit_preset", lambda name, **kw: broken)
    result = FP.fit_presets([], out_dir=out, photons=100, artist={"wax": {"albedo": [0.5] * 3, "d_mm": [1.0] * 3}},
                            plots=False, readme=False, log=lambda s: None)
    assert result["written"] == [] and "wax" in result["failed"] and "with 100 photons" in result["failed"]["wax"]
    assert json.loads((out / "wax.json").read_text()) == good
    # a table of the wrong shape is refused with the file named, not an IndexError
    (out / "odd.json").write_text(json.dumps(dict(good, transmittance=dict(tr, thickness_mm=[0.5, 1.0]))))
    with pytest.raises(_io.SSSInputError, match=r"odd.json: transmittance \(thickness_mm, T and resolved: a list per "
                                                r"channel\) is not a table of numbers \(IndexError"):
        _presets.load_preset(out / "odd.json")


def test_measured_csv_errors_name_the_file_and_row(tmp_path):
    bad = tmp_path / "m.csv"
    bad.write_text("name,sigma_s_prime_r,sigma_s_prime_g,sigma_s_prime_b,sigma_a_r,sigma_a_g,sigma_a_b\n"
                   "goo,1,1,1,0.1,0.1\n")
    with pytest.raises(_io.SSSInputError, match=r"m.csv: line 2 lacks sigma_a_b"):
        FP.measured_materials(bad)
    bad.write_text("name,sigma_s_prime_r,sigma_s_prime_g,sigma_s_prime_b,sigma_a_r,sigma_a_g,sigma_a_b\n"
                   "goo,1,1,1,0.1,-0.1,0.1\n")
    with pytest.raises(_io.SSSInputError, match=r"line 2 \(goo\): coefficients must be finite and >= 0"):
        FP.measured_materials(bad)
    # a header and no rows: an error, not an empty list of materials (`fit --list` printed "measured:", exit 0)
    bad.write_text("name,sigma_s_prime_r,sigma_s_prime_g,sigma_s_prime_b,sigma_a_r,sigma_a_g,sigma_a_b\n")
    with pytest.raises(_io.SSSInputError, match=r"m.csv: no materials"):
        FP.measured_materials(bad)


HEADER = "name,sigma_s_prime_r,sigma_s_prime_g,sigma_s_prime_b,sigma_a_r,sigma_a_g,sigma_a_b"


@pytest.mark.parametrize("text, message", [
    # a row's name became the preset's file name unchecked: "../../evil" wrote outside --out
    (f"{HEADER}\n../../evil,1,1,1,0.1,0.1,0.1\n", r"line 2: preset name '../../evil': use letters"),
    (f"{HEADER}\nfoo,1,1,1,0.1,0.1,0.1\nfoo,2,2,2,0.1,0.1,0.1\n", r"line 3: material 'foo' is given twice"),
    (f"{HEADER}\nskin,1,1,1,0.1,0.1,0.1\n", r"line 2: 'skin' is an artist material's name"),
    (f"{HEADER}\nfoo,1,1,1,0.1,0.1,0.1,7\n", r"line 2 has 1 value\(s\) more than the header's columns"),
    # a header without the columns was "row 2 lacks name, ..."; line numbers counted without the comments
    ("material,s_r,s_g,s_b,a_r,a_g,a_b\nfoo,1,1,1,0.1,0.1,0.1\n", (r"the header \(line 1\) lacks name, .* it has "
                                                                  r"'material', 's_r'")),
    (f"# Jensen 2001\n#\n{HEADER}\nfoo,1,1,1,0.1,0.1,0.1\nbar,x1,1,1,0.1,0.1,0.1\n", r"line 5 \(bar\): could not"),
    (f"{HEADER}\nfoo,0,0,0,0.1,0.1,0.1\n", r"line 2 \(foo\): .*sigma_s' > 0 per channel"),
])
def test_measured_csv_rows_are_checked_where_they_are(tmp_path, text, message):
    path = tmp_path / "m.csv"
    path.write_text(text)
    with pytest.raises(_io.SSSInputError, match=message):
        FP.measured_materials(path)


def test_measured_csv_as_spreadsheets_write_it(tmp_path):
    # Excel's "CSV UTF-8" starts with a byte-order mark ("row 2 lacks name" before); Latin-1 text named the codec
    # but not the file; spaces after the commas
    path = tmp_path / "m.csv"
    path.write_bytes(("\ufeff" + HEADER.replace(",", ", ") + "\r\nfoo, 1, 1, 1, 0.1, 0.1, 0.1\r\n").encode("utf-8"))
    assert FP.measured_materials(path) == {"foo": {"sigma_s_prime": [1.0] * 3, "sigma_a": [0.1] * 3}}
    path.write_bytes((HEADER + "\ncr\xe8me,1,1,1,0.1,0.1,0.1\n").encode("latin-1"))
    with pytest.raises(_io.SSSInputError, match=r"m.csv: not UTF-8 text"):
        FP.measured_materials(path)


def test_engine_table_covers_every_preset_and_engine():
    presets = list(_all_presets().values())
    rows = FP.engine_rows(presets)
    assert [r["preset"] for r in rows] == [p["name"] for p in presets]
    for p, row in zip(presets, rows):
        eng = p["errors"]["engines"]
        for name in FP.ENGINE_ORDER:
            b, m, lost = row[name].split(" / ")
            assert float(b) == pytest.approx(max(eng["vs_burley"][name]["error_relative_l2"]), abs=5e-4)
            assert float(m) == pytest.approx(max(eng["vs_montecarlo"][name]["error_relative_l2"]), abs=5e-4)
        assert row["closest to MC"] == min(FP.ENGINE_ORDER,
                                           key=lambda n: max(eng["vs_montecarlo"][n]["error_relative_l2"]))
        # engines that renormalise their kernel return all of the albedo (Cycles' bssrdf_burley_pdf, HDRP's weight
        # sum, EEVEE's normalised kernel, Jimenez's normalised taps)
        for name in ("cycles", "hdrp", "eevee", "jimenez"):
            np.testing.assert_allclose(eng["vs_burley"][name]["energy_lost"], 0.0, atol=1e-9)
        # UE5 clamps Surface Albedo to >= 0.009 (SubsurfaceProfile.cpp): a darker channel gains 1 - 0.009/A
        A = np.array(p["albedo"])
        expected = np.where(A < 0.009, 1 - 0.009 / np.maximum(A, 1e-300), 0.0)
        np.testing.assert_allclose(eng["vs_burley"]["unreal"]["energy_lost"], expected, atol=1e-6)
    # the table in fits/README.md is the one these files give (the script wrote both)
    readme = (FITS / "README.md").read_text()
    for line in _markdown_table(rows):
        assert line in readme


def test_the_plot_draws_the_monte_carlo_at_the_preset_s_mean_free_path(tmp_path, monkeypatch):
    # the cached profiles are per mean free path and serve every material of their albedo: a re-fit of a material
    # with another d reused them while the cache kept the first run's mean free path, and the plot drew the Monte
    # Carlo curve at that length (2x compressed against Burley d = 6 after a fit at d = 3)
    import matplotlib.axes

    drawn = []
    real = matplotlib.axes.Axes.errorbar
    monkeypatch.setattr(matplotlib.axes.Axes, "errorbar",
                        lambda self, x, y, **kw: drawn.append(np.asarray(x)) or real(self, x, y, **kw))
    preset = json.loads((FITS / "ketchup.json").read_text())
    (tmp_path / "montecarlo").mkdir()
    shutil.copy(FITS / "montecarlo" / "ketchup.json", tmp_path / "montecarlo" / "ketchup.json")
    FP.plot_preset(preset, tmp_path)
    wider = json.loads(json.dumps(preset))
    wider["burley"]["mean_free_path_mm"] = [2 * v for v in preset["burley"]["mean_free_path_mm"]]
    FP.plot_preset(wider, tmp_path)
    for c in range(3):
        np.testing.assert_allclose(drawn[3 + c], 2 * drawn[c], rtol=1e-12)


def test_the_folder_readme_names_an_invalid_preset_instead_of_failing(tmp_path):
    # a folder holding a preset that does not load (written before fits checked what they write, or edited by hand)
    # made every later fit into it fail at the README, after its own preset was written
    shutil.copy(FITS / "ketchup.json", tmp_path / "ketchup.json")
    (tmp_path / "broken.json").write_text("{\"name\": \"broken\"}")
    readme = FP.write_presets_readme(tmp_path).read_text()
    assert "| ketchup |" in readme and "broken.json:" in readme and "Files left out" in readme
