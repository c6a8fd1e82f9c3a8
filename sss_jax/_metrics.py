"""Error metrics on the host (NumPy and colour-science), restricted to SSS pixels and split per material.

Domain: linear, scene-referred Rec. 709 / sRGB-primaries RGB. For CIEDE2000 the images are scaled by
``2**exposure`` and read as relative XYZ with the stated white (D65 by default): Y = 1 is the diffuse white, so
an exposure that maps the scene's white to 1 makes the Lab values meaningful (the report states the one it uses).
HDR-ꟻLIP (NVIDIA's ``flip-evaluator``) reads the same linear RGB as high dynamic range: it tone maps both images
(ACES) at a range of exposures and keeps each pixel's largest LDR-ꟻLIP error, so its map is in [0, 1] with no
exposure to choose; ``flip`` states the range it used.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from jaxtyping import ArrayLike

from ._scene import surface_mask

__all__ = ["rel_l2", "rmse", "max_error", "delta_e_2000", "flip", "flip_exposures", "energy_ratio", "metrics_by_material", "sss_mask"]


def _check(output: ArrayLike, reference: ArrayLike, mask: ArrayLike | None, names=("output", "reference")):
    out = np.asarray(output, np.float64)
    ref = np.asarray(reference, np.float64)
    if out.shape != ref.shape:
        raise ValueError(f"{names[0]} shape {out.shape} does not match {names[1]} shape {ref.shape}")
    for name, a in zip(names, (out, ref)):
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} has non-finite values")
    if mask is None:
        mask = np.ones(out.shape[:2], bool)
    mask = np.asarray(mask, bool)
    if mask.shape != out.shape[:2]:
        raise ValueError(f"mask shape {mask.shape} does not match the images' {out.shape[:2]}")
    if not mask.any():
        raise ValueError("mask selects no pixels")
    return out[mask], ref[mask]


def rel_l2(output, reference, *, mask=None) -> float:
    """Relative L2 error ``||output - reference||_2 / ||reference||_2`` over the masked pixels, all channels
    (dimensionless; the absolute ``||output - reference||_2`` where the reference is all zero).

    The one owner of this metric in the package. ``output``, ``reference``: ``(H, W, C)`` (or ``(N, C)`` rows of
    pixels), any units as long as they agree; ``mask``: ``(H, W)`` (or ``(N, C)``) bool, default every pixel."""
    o, r = _check(output, reference, mask)
    norm = np.linalg.norm(r)
    return float(np.linalg.norm(o - r) / norm) if norm > 0 else float(np.linalg.norm(o - r))


def rmse(output, reference, *, mask=None) -> float:
    o, r = _check(output, reference, mask)
    return float(np.sqrt(np.mean((o - r) ** 2)))


def max_error(output, reference, *, mask=None) -> float:
    o, r = _check(output, reference, mask)
    return float(np.max(np.abs(o - r)))


def _lab(rgb: np.ndarray, exposure: float, illuminant: str) -> np.ndarray:
    import colour

    white = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"][illuminant]
    xyz = colour.RGB_to_XYZ(np.maximum(rgb, 0.0) * 2.0**exposure, colour.RGB_COLOURSPACES["sRGB"],
                            illuminant=white, apply_cctf_decoding=False)
    return colour.XYZ_to_Lab(xyz, white)


def delta_e_2000(output, reference, *, mask=None, exposure: float = 0.0, illuminant: str = "D65") -> dict[str, Any]:
    """CIEDE2000 per pixel (through colour-science) and its mean, 95th percentile and maximum over the mask."""
    import colour

    out = np.asarray(output, np.float64)
    ref = np.asarray(reference, np.float64)
    _check(out, ref, mask)
    de = colour.delta_E(_lab(out, exposure, illuminant), _lab(ref, exposure, illuminant), method="CIE 2000")
    m = np.ones(out.shape[:2], bool) if mask is None else np.asarray(mask, bool)
    sel = de[m]
    return {"map": np.where(m, de, 0.0), "mean": float(sel.mean()), "p95": float(np.percentile(sel, 95)),
            "max": float(sel.max()), "exposure": exposure, "illuminant": illuminant}


# HDR-FLIP's defaults (Andersson et al., "Visualizing Errors in Rendered High Dynamic Range Images", Eurographics
# 2021, and flip-evaluator's FLIP.h): 67 pixels per degree (a 0.7 m wide 3840 px monitor seen from 0.7 m), the ACES
# fit with its 0.6 pre-exposure cancelled, and the exposure range from the reference's luminance: the shortest
# exposure maps its brightest pixel, the longest its median, to the tone curve's 0.85.
FLIP_PPD = 67.02064514160156
_ACES = (0.6 * 0.6 * 2.51, 0.6 * 0.03, 0.0, 0.6 * 0.6 * 2.43, 0.6 * 0.59, 0.14)


def _aces_input_for(t: float) -> float:
    """The largest linear x >= 0 the ACES fit maps to ``t``: (a x^2 + b x + c) / (d x^2 + e x + f) = t."""
    a0, b0, c0, d0, e0, f0 = _ACES
    a, b, c = a0 - t * d0, b0 - t * e0, c0 - t * f0
    return float(max(np.roots([a, b, c]).real))


def flip_exposures(reference, *, mask=None) -> tuple[float, float, int]:
    """HDR-ꟻLIP's exposure range ``(start, stop, count)`` in stops for a linear RGB ``reference`` ``(H, W, 3)``:
    ``start = log2(x / Y_max)``, ``stop = log2(x / Y_median)`` with ``x`` the ACES input mapped to 0.85 and ``Y`` the
    Rec. 709 luminance over the masked pixels (``mask``: ``(H, W)`` bool, default all; ꟻLIP's own rule takes every
    pixel, which on a frame that is mostly background puts the median at 0), ``count = max(2, ceil(stop - start))``.
    """
    ref = np.maximum(np.asarray(reference, np.float64), 0.0)
    sel = ref[np.ones(ref.shape[:2], bool) if mask is None else np.asarray(mask, bool)]
    lum = sel @ np.array([0.2126, 0.7152, 0.0722])
    if not np.any(lum > 0):
        raise ValueError("reference is black on every masked pixel: HDR-ꟻLIP has no exposure range")
    # FLIP.h takes element size/2 of the sorted luminances as the median (nth_element), not the mean of the middle two
    y_max, y_median = float(lum.max()), float(np.sort(lum)[lum.size // 2])
    x = _aces_input_for(0.85)
    start = float(np.log2(x / y_max))
    stop = float(np.log2(x / y_median)) if y_median > 0 else start
    return start, stop, int(max(2.0, np.ceil(stop - start)))


def flip(output, reference, *, mask=None, exposures: tuple[float, float, int] | None = None,
         ppd: float = FLIP_PPD) -> dict[str, Any]:
    """HDR-ꟻLIP of linear scene-referred RGB ``output`` against ``reference`` (both ``(H, W, 3)``, negative values
    read as 0), through NVIDIA's ``flip-evaluator``: the per-pixel error ``map`` ``(H, W)`` in [0, 1] (0 off the
    mask), its ``mean`` over the mask, and the settings used: ``start_exposure``/``stop_exposure`` (stops) and
    ``num_exposures`` (``exposures``, default ``flip_exposures(reference, mask=mask)``), ``ppd`` (pixels per degree),
    ``tonemapper``. The map is computed on the whole image (its filters reach across the mask's edge)."""
    try:
        import flip_evaluator
    except ImportError as e:  # a real dependency; a broken install says how to mend it
        raise ImportError("HDR-ꟻLIP needs NVIDIA's flip-evaluator: pip install 'flip-evaluator>=1.7'") from e

    out = np.asarray(output, np.float64)
    ref = np.asarray(reference, np.float64)
    _check(out, ref, mask)
    if not ppd > 0:
        raise ValueError(f"ppd (pixels per degree) must be positive, got {ppd!r}")
    m = np.ones(out.shape[:2], bool) if mask is None else np.asarray(mask, bool)
    start, stop, count = flip_exposures(ref, mask=m) if exposures is None else exposures
    if not (np.isfinite(start) and np.isfinite(stop) and start <= stop and int(count) >= 2):
        raise ValueError(f"exposures must be (start, stop, count) with start <= stop and count >= 2, "
                         f"got {exposures!r}")
    params = {"ppd": float(ppd), "startExposure": float(start), "stopExposure": float(stop),
              "numExposures": int(count), "tonemapper": "ACES"}
    as32 = lambda a: np.ascontiguousarray(np.maximum(a, 0.0), np.float32)
    error, _, used = flip_evaluator.evaluate(as32(ref), as32(out), "HDR", applyMagma=False, computeMeanError=False,
                                             parameters=params)
    error = np.asarray(error, np.float64).reshape(out.shape[:2])
    return {"map": np.where(m, error, 0.0), "mean": float(error[m].mean()),
            "start_exposure": float(used["startExposure"]), "stop_exposure": float(used["stopExposure"]),
            "num_exposures": int(used["numExposures"]), "ppd": float(used["ppd"]), "tonemapper": "ACES"}


def energy_ratio(output, input, *, mask=None) -> np.ndarray:
    """Output over input energy per channel, ``(3,)``: 1 for a pass that redistributes light, > 1 when it adds."""
    o, i = _check(output, input, mask, names=("output", "input"))
    total = i.sum(axis=0)
    return np.where(total > 0, o.sum(axis=0) / np.where(total > 0, total, 1.0), np.nan)


def sss_mask(depth, material_id=None) -> np.ndarray:
    depth = np.asarray(depth)
    mask = surface_mask(depth)  # a background's huge finite depth (Blender's 1e10) is no surface
    if material_id is not None:
        mask &= np.asarray(material_id) > 0
    return mask


def metrics_by_material(output, reference, input, material_id, *, depth=None, exposure: float = 0.0) -> dict:
    """Every metric over all SSS pixels (``"all"``) and per material id (``"id1"``, ...)."""
    ids = np.asarray(material_id)
    base = sss_mask(depth if depth is not None else np.ones(ids.shape), ids)
    groups = {"all": base}
    for k in sorted(int(v) for v in np.unique(ids[base])):
        groups[f"id{k}"] = base & (ids == k)
    result = {}
    for name, m in groups.items():
        if not m.any():
            continue
        de = delta_e_2000(output, reference, mask=m, exposure=exposure)
        result[name] = {
            "pixels": int(m.sum()),
            "relative_l2": rel_l2(output, reference, mask=m),
            "rmse": rmse(output, reference, mask=m),
            "max_error": max_error(output, reference, mask=m),
            "delta_e_2000_mean": de["mean"], "delta_e_2000_p95": de["p95"], "delta_e_2000_max": de["max"],
            "energy_ratio": energy_ratio(output, input, mask=m).tolist(),
        }
    return result
