"""Error metrics on the host (NumPy and colour-science), restricted to SSS pixels and split per material.

Domain: linear, scene-referred Rec. 709 / sRGB-primaries RGB. For CIEDE2000 the images are scaled by
``2**exposure`` and read as relative XYZ with the stated white (D65 by default): Y = 1 is the diffuse white, so
an exposure that maps the scene's white to 1 makes the Lab values meaningful (the report states the one it uses).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from jaxtyping import ArrayLike

__all__ = ["rel_l2", "rmse", "max_error", "delta_e_2000", "energy_ratio", "metrics_by_material", "sss_mask"]


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


def energy_ratio(output, input, *, mask=None) -> np.ndarray:
    """Output over input energy per channel, ``(3,)``: 1 for a pass that redistributes light, > 1 when it adds."""
    o, i = _check(output, input, mask, names=("output", "input"))
    total = i.sum(axis=0)
    return np.where(total > 0, o.sum(axis=0) / np.where(total > 0, total, 1.0), np.nan)


def sss_mask(depth, material_id=None) -> np.ndarray:
    depth = np.asarray(depth)
    mask = np.isfinite(depth) & (depth > 0)
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
