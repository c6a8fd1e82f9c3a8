"""Metrics against independent values: Sharma et al.'s CIEDE2000 test data and hand-computed cases."""

import colour
import numpy as np
import pytest

from sss_jax import _metrics as M


@pytest.mark.parametrize("lab1, lab2, expected", [
    # G. Sharma, W. Wu, E. N. Dalal, "The CIEDE2000 color-difference formula: implementation notes, supplementary test
    # data, and mathematical observations", Color Res. Appl. 30 (2005), Table 1, pairs 1, 7, 17 and 25
    ((50.0000, 2.6772, -79.7751), (50.0000, 0.0000, -82.7485), 2.0425),
    ((50.0000, 0.0000, 0.0000), (50.0000, -1.0000, 2.0000), 2.3669),
    ((50.0000, 2.5000, 0.0000), (73.0000, 25.0000, -18.0000), 27.1492),
    ((60.2574, -34.0099, 36.2677), (60.4626, -34.1751, 39.4387), 1.2644),
])
def test_delta_e_2000_sharma_table(lab1, lab2, expected, monkeypatch):
    # feed Lab straight through: the metric's conversion is tested separately below
    monkeypatch.setattr(M, "_lab", lambda rgb, exposure, illuminant: rgb)
    a = np.asarray(lab1, float).reshape(1, 1, 3)
    b = np.asarray(lab2, float).reshape(1, 1, 3)
    assert M.delta_e_2000(a, b)["mean"] == pytest.approx(expected, abs=1e-4)


def test_delta_e_conversion_matches_colour_science_example():
    # white in linear sRGB at exposure 0 is Y = 1: L* = 100, a* = b* = 0 under D65 (to the 4-digit precision of the
    # sRGB matrix against the CIE chromaticity of D65: |a*|, |b*| < 0.01)
    white = np.ones((1, 1, 3))
    lab = M._lab(white, 0.0, "D65")
    np.testing.assert_allclose(lab[0, 0], [100.0, 0.0, 0.0], atol=1e-2)
    # one stop down: Y = 0.5 -> L* = 116 * 0.5^(1/3) - 16 = 76.0693 (CIE 1976 formula)
    lab = M._lab(white, -1.0, "D65")
    assert lab[0, 0, 0] == pytest.approx(116 * 0.5 ** (1 / 3) - 16, abs=1e-3)
    # and the whole path agrees with colour-science called directly
    rng = np.random.default_rng(0)
    a, b = rng.uniform(0, 1, (4, 5, 3)), rng.uniform(0, 1, (4, 5, 3))
    cs = colour.RGB_COLOURSPACES["sRGB"]
    d65 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]
    to_lab = lambda x: colour.XYZ_to_Lab(colour.RGB_to_XYZ(x, cs, illuminant=d65, apply_cctf_decoding=False), d65)
    expected = colour.delta_E(to_lab(a), to_lab(b), method="CIE 2000")
    np.testing.assert_allclose(M.delta_e_2000(a, b)["map"], expected, rtol=1e-12)


def test_hand_computed_errors_and_masks():
    ref = np.zeros((2, 2, 3))
    ref[0, 0] = [3.0, 0.0, 4.0]  # |ref| = 5 over the whole image
    out = ref.copy()
    out[0, 0, 0] += 1.0
    out[1, 1, 2] = 2.0
    assert M.relative_l2(out, ref) == pytest.approx(np.sqrt(1 + 4) / 5)
    assert M.rmse(out, ref) == pytest.approx(np.sqrt(5 / 12))
    assert M.max_error(out, ref) == 2.0
    mask = np.array([[True, False], [False, False]])
    assert M.relative_l2(out, ref, mask=mask) == pytest.approx(1 / 5)
    np.testing.assert_allclose(M.energy_ratio(out, ref, mask=mask), [4 / 3, np.nan, 1.0])


def test_metrics_by_material_splits_and_counts():
    rng = np.random.default_rng(1)
    ref = rng.uniform(0.1, 1, (4, 6, 3))
    out = ref * 1.1
    ids = np.zeros((4, 6), int)
    ids[:, 2:4] = 1
    ids[:, 4:] = 2
    res = M.metrics_by_material(out, ref, ref, ids)
    assert set(res) == {"all", "id1", "id2"}
    assert res["id1"]["pixels"] == 8 and res["all"]["pixels"] == 16
    assert res["all"]["relative_l2"] == pytest.approx(0.1)
    np.testing.assert_allclose(res["id2"]["energy_ratio"], 1.1)


@pytest.mark.parametrize("call, message", [
    (lambda: M.rmse(np.zeros((2, 2, 3)), np.zeros((2, 3, 3))), "does not match reference shape"),
    (lambda: M.rmse(np.full((2, 2, 3), np.nan), np.zeros((2, 2, 3))), "output has non-finite values"),
    (lambda: M.rmse(np.zeros((2, 2, 3)), np.zeros((2, 2, 3)), mask=np.zeros((2, 2), bool)), "mask selects no pixels"),
])
def test_metric_errors(call, message):
    with pytest.raises(ValueError, match=message):
        call()
