"""Match offline: fit a real-time technique's material to a path-traced render of the same view.

Given the screen-space inputs of one or more frames of a shot (irradiance, depth, material ids: what ``apply``
reads) and an offline render of each (e.g. Cycles' Combined pass), find per material id the parameters that make
the technique look like the offline render:

- ``burley``: Burley's d per channel (mm), and the albedo with ``fit_albedo``;
- ``separable``: the two-Gaussian kernel (``w``, ``sigma_near_mm``, ``sigma_far_mm`` per channel) (+ albedo);
- ``sta``: the STA parameters (``distortion``, ``power``, ``scale``, ``ambient``, ``thickness_mm``) (+ albedo).

The metric is ``rel_l2 = ||out - truth||_2 / ||truth||_2`` over RGB on a material's SSS pixels (finite depth and
id == k; "all": id > 0), pooled over frames. The objective is the sum over materials of that error squared
(``loss="l2"``) or of its Huber version (``loss="huber"``, the default): each pixel's residual, in units of the
material's mean truth value, counts quadratically up to ``huber_delta`` and linearly beyond, so path-tracing
fireflies and what screen space cannot know (light entering unseen surfaces) pull less on the fit. Errors reported
before and after are always the plain ``rel_l2``.

Which pixels are scored (``score``): by default (``"held"``) only those whose kernel the frame holds -- at least
``held_fraction`` (``HELD_FRACTION``, 0.95) of the starting kernel's energy inside the frame, from its 1D marginal beyond each frame
edge (``held_mask``) --, so that d is not bent to make up for light a screen-space pass cannot see beyond the frame
(a close-up's light from outside it); ``"all"`` scores every SSS pixel. The result says which pixels it scored
(``MatchResult.scored``: counts per frame and material, the rule; ``score_masks``: the masks) and reports the errors
on the scored pixels beside the plain ones on all SSS pixels.

Solver: optimistix Levenberg–Marquardt on the residual vector, parameters in log space (d, widths, STA terms:
positive) or logit space (albedo, ``w``: in (0, 1)), ``throw=False``; its result code and iterations are kept.
Several frames are fitted at once (one material, many views); frames given as ``holdout`` are not fitted, only
measured before and after.
"""

from __future__ import annotations

import base64
import dataclasses
import html
import io
import math
import os
import pathlib
import time
from collections.abc import Mapping, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._batch import _has_seed, _with_seed, frame_number, frame_seed
from ._checks import check_host_count, check_host_range
from ._io import SSSInputError, check_writable, display_transform, no_focal_length, read_frame, write_bytes_atomic
from ._kernels import _check_taps
from ._evaluate import read_truth
from ._materials import BurleyMaterial, DirectionalLight, STAParams, TwoGaussianMaterial
from ._scene import Buffers, Camera, surface_mask, validate_buffers
from ._techniques._base import AbstractTechnique

__all__ = ["MATCH_TECHNIQUES", "MATCH_LOSSES", "MATCH_SCORES", "MatchFrame", "MatchResult", "match_frame",
           "load_match_frame", "read_truth", "match_render", "match_report_html", "write_match_html", "held_mask",
           "edge_loss"]

MATCH_TECHNIQUES = ("burley", "separable", "sta")  # the registry names of the classes in _FITS (a test checks)
MATCH_LOSSES = ("huber", "l2")
MATCH_SCORES = ("held", "all")
# the share of a scored pixel's kernel inside the frame: 0.99 needs 8.2 d from every edge, which leaves no pixel of a
# close-up (skin1 at 8 px/mm, red d 7 px, a 160x120 frame: tests/data/mitsuba/skin_closeup); 0.95 needs 4.1 d
HELD_FRACTION = 0.95
METRIC = "rel_l2 = ||out - truth||_2 / ||truth||_2 over RGB on the material's SSS pixels (finite depth, id == k; " \
         "'all': id > 0), pooled over the frames"
_MAX_ID = 255
_FLOOR = 1e-4  # smallest start value of a log-space parameter (an STA ambient of 0 starts here)


# ------------------------------------------------------------------------------------------------------------------
# frames
# ------------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class MatchFrame:
    """One view to match: the technique's input buffers, the camera, and the offline render of the same view.

    ``truth``: ``(H, W, 3)`` float32 linear RGB; ``material_id``: ``(H, W)`` int32, 0 where there is no SSS
    surface (no id channel: 1 on every pixel of finite depth). ``number``: the frame's number in its sequence, mixed
    into a seeded technique's seed as ``apply`` mixes it (``frame_seed``): ``load_match_frame`` takes it from the
    file name as ``apply`` does, so the fitted material renders through ``apply`` with the rotations it was fitted
    with."""

    buffers: Buffers
    camera: Camera
    truth: np.ndarray
    material_id: np.ndarray
    name: str = "frame"
    number: int = 0

    def __post_init__(self):  # every check match_frame's frames pass, also for a frame made directly
        name = self.name
        if not isinstance(self.buffers, Buffers) or not isinstance(self.camera, Camera):
            raise TypeError(f"{name}: MatchFrame needs Buffers and a Camera, got "
                            f"{type(self.buffers).__name__} and {type(self.camera).__name__}")
        shape = tuple(self.buffers.depth.shape)
        if np.shape(self.truth) != shape + (3,) or np.shape(self.material_id) != shape:
            raise SSSInputError(f"{name}: truth {np.shape(self.truth)} and material_id "
                                f"{np.shape(self.material_id)} must be {shape + (3,)} and {shape}, as the buffers")
        check_host_count(self.number, f"{name}: number", lo=0, hi=2**63 - 1)
        truth, ids = np.asarray(self.truth), np.asarray(self.material_id)
        if not np.all(np.isfinite(truth)):
            raise SSSInputError(f"{name}: truth has {int(np.sum(~np.isfinite(truth)))} non-finite values")
        # the buffers' own check (a NaN irradiance on an SSS pixel left the solver at "nonfinite_input" with a NaN
        # error, one on the background a fit that "converged" without moving): named as every technique names it
        try:
            validate_buffers(self.buffers, physical=False, name=name)
        except ValueError as exc:
            raise SSSInputError(str(exc)) from None
        if not np.issubdtype(ids.dtype, np.integer) or (ids.size and ids.min() < 0):
            raise SSSInputError(f"{name}: material_id must be integers >= 0 (0: no SSS), got {ids.dtype}"
                                + (f" down to {ids.min()}" if ids.size and np.issubdtype(ids.dtype, np.number) else ""))
        if not np.any(ids > 0):
            raise SSSInputError(f"{name}: no SSS pixels (a surface's depth and material id > 0)")
        if ids.max() > _MAX_ID:
            raise SSSInputError(f"{name}: material id {int(ids.max())} is above {_MAX_ID}")
        # the error is ||out - truth|| / ||truth|| over the SSS pixels: a truth black there (or negative overall) has
        # nothing to match (the fit "succeeded" without moving, or fitted garbage to -truth)
        if not np.sum(truth[ids > 0], dtype=np.float64) > 0:
            raise SSSInputError(f"{name}: truth is black (or negative overall) on the frame's SSS pixels: nothing to "
                                "match")


def match_frame(buffers: Buffers, camera: Camera, truth, *, name: str = "frame", number: int = 0) -> MatchFrame:
    """A ``MatchFrame`` from arrays; ``truth`` is ``(H, W, 3)`` linear RGB of the same view as ``buffers``;
    ``number``: the frame's number in its sequence (``MatchFrame``). The material ids: the buffers' (1 on every
    surface pixel where they have none), 0 off the surface."""
    if not isinstance(buffers, Buffers) or not isinstance(camera, Camera):
        raise TypeError(f"{name}: match_frame needs Buffers and a Camera, got {type(buffers).__name__} and "
                        f"{type(camera).__name__}")
    truth = np.asarray(truth, np.float32)
    shape = tuple(buffers.depth.shape)
    if truth.shape != shape + (3,):
        raise SSSInputError(f"{name}: truth is {truth.shape}, the buffers are {shape} (expected truth {shape + (3,)})")
    ids = (np.ones(shape, np.int32) if buffers.material_id is None else np.asarray(buffers.material_id, np.int32))
    # a surface as every technique reads it (a background's huge finite depth, Blender's 1e10, is none)
    ids = np.where(surface_mask(np.asarray(buffers.depth)), ids, 0).astype(np.int32)
    return MatchFrame(buffers, camera, truth, ids, name, number)


def load_match_frame(render: str | os.PathLike, truth: str | os.PathLike, *, truth_channels=None, channel_map=None,
                     focal_px: float | None = None, mm_per_unit: float | None = None, depth_kind: str = "planar",
                     use_albedo_pass: bool = True) -> MatchFrame:
    """A ``MatchFrame`` from the technique's input EXR (read as ``apply`` reads it: Blender multi-layer passes,
    generic channels or a channel map; camera from the arguments, the header or a sidecar JSON) and the truth EXR
    (``read_truth``). ``use_albedo_pass=False`` drops the albedo buffer so the material's albedo decides (as
    ``apply --albedo`` does)."""
    frame = read_frame(render, channel_map=channel_map, focal_px=focal_px, mm_per_unit=mm_per_unit,
                       depth_kind=depth_kind)
    if frame.focal_px is None:
        raise no_focal_length(render)
    rgb = read_truth(truth, truth_channels, frame=frame)  # the report's reader: one rule for a truth
    camera = frame.camera()
    return match_frame(frame.to_buffers(use_albedo=use_albedo_pass), camera, rgb, name=pathlib.Path(render).name,
                       number=frame_number(render, 0))  # the number `apply` of this file alone gives it


# ------------------------------------------------------------------------------------------------------------------
# parameters: natural <-> unconstrained
# ------------------------------------------------------------------------------------------------------------------


def _rows(x, count: int, name: str) -> np.ndarray:
    """``(count, 3)`` float64 from a ``(3,)``, ``(1, 3)`` or ``(count, 3)`` table."""
    a = np.asarray(x, np.float64)
    a = a.reshape(1, -1) if a.ndim <= 1 else a
    if a.shape[-1] != 3 and a.shape[-1] != 1:
        raise ValueError(f"{name} must have 3 channels, got shape {np.shape(x)}")
    if a.shape[0] == 1:
        a = np.broadcast_to(a, (count, a.shape[-1]))
    if a.shape[0] < count:
        raise ValueError(f"{name} has {a.shape[0]} material rows; the frames use material ids up to {count}")
    return np.broadcast_to(a[:count], (count, 3)).copy()


def _log(x) -> np.ndarray:
    return np.log(np.maximum(np.asarray(x, np.float64), _FLOOR))


def _logit(x) -> np.ndarray:
    p = np.clip(np.asarray(x, np.float64), _FLOOR, 1 - _FLOOR)
    return np.log(p / (1 - p))


def _two_gaussian_from_burley(material: BurleyMaterial, count: int) -> TwoGaussianMaterial:
    """The start of a separable fit from a Burley material: the profile-space two-Gaussian fit per row."""
    from ._fitting import fit_two_gaussian_to_burley

    d = _rows(material.d_mm, count, "d_mm")
    fits = {}
    rows = {"w": [], "sigma_near_mm": [], "sigma_far_mm": []}
    for row in d:
        key = tuple(np.round(row, 9))
        if key not in fits:
            fits[key] = fit_two_gaussian_to_burley(np.maximum(row, 1e-3))
        for k in rows:
            rows[k].append(fits[key][k])
    return TwoGaussianMaterial(_rows(material.albedo, count, "albedo"), rows["w"], rows["sigma_near_mm"],
                               rows["sigma_far_mm"])


class _AbstractFit:
    """How a technique's material is fitted: its unconstrained parameters (``start``), their natural values
    (``natural``), the material they make (``material``), a render with it (``render``) and what the result records
    (``record``). One subclass per technique class (``_FITS``); the fit asks it, never the technique's name."""

    # options the fit needs of a technique built from its name (continuous fetches: smooth in the parameters)
    build: Mapping[str, Any] = {}

    def start(self, material, count: int) -> tuple[dict, np.ndarray]:
        raise NotImplementedError

    def natural(self, y: Mapping[str, Any], albedo, xp) -> dict[str, Any]:
        return {"albedo": albedo, **{k[4:]: xp.exp(v) for k, v in y.items() if k.startswith("log_")}}

    def material(self, p: Mapping[str, Any]):
        raise NotImplementedError

    def render(self, technique, frame, p: Mapping[str, Any]):
        return technique(frame.buffers, self.material(p), frame.camera)

    def beyond_edge(self, material, distance_px: np.ndarray, px_per_mm: np.ndarray) -> np.ndarray | None:
        """Host side: per pixel and channel ``(..., 3)``, the share of ``material``'s kernel (its rows already picked
        per pixel: arrays ``(..., 3)``) beyond a straight frame edge ``distance_px`` away; None: the technique has no
        kernel that reaches past the frame (every pixel is held)."""
        return None

    def record(self, technique, p_fit: Mapping[str, Any], ids) -> tuple[dict, dict | None]:
        """The technique's options the fit was for, and the engines' blocks of the fitted material (or None)."""
        count = technique.count_option
        return ({} if count is None else {count: int(getattr(technique, count))}), None


class _BurleyFit(_AbstractFit):
    build = {"interpolation": "bilinear"}

    def start(self, material, count):
        if not isinstance(material, BurleyMaterial):
            raise TypeError(f"technique 'burley' starts from a BurleyMaterial, got {type(material).__name__}")
        d = _rows(material.d_mm, count, "d_mm")
        if not np.all(d > 0):  # d = 0 is the identity: no width to move, the fit "succeeded" where it started
            raise ValueError(f"the start's d must be > 0 in every channel to fit it (d = 0 renders no scattering, "
                             f"a point the fit cannot leave), got {d.tolist()}")
        return {"log_d_mm": _log(d)}, _rows(material.albedo, count, "albedo")

    def material(self, p):
        return BurleyMaterial(p["albedo"], p["d_mm"])

    def beyond_edge(self, material, distance_px, px_per_mm):
        """The 1D marginal of ``R(r) = (e^{-r/d} + e^{-r/3d}) / (8 pi d r)`` is ``(K0(x/d) + K0(x/3d)) / (4 pi d)``
        (``int e^{-sqrt(x^2+y^2)/d} / sqrt(x^2+y^2) dy = 2 K0(|x|/d)``), so the share beyond x is
        ``[(pi/2 - int_0^{x/d} K0) + 3 (pi/2 - int_0^{x/3d} K0)] / (4 pi)`` (scipy ``iti0k0``; 1/2 at the edge)."""
        from scipy.special import iti0k0

        d = np.asarray(material["d_mm"], np.float64) * px_per_mm
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.where(d > 0, distance_px / np.where(d > 0, d, 1.0), np.inf)

        def tail(z):
            finite = np.isfinite(z)
            return np.where(finite, np.pi / 2 - iti0k0(np.where(finite, z, 0.0))[1], 0.0)

        return (tail(u) + 3 * tail(u / 3)) / (4 * np.pi)

    def record(self, technique, p_fit, ids):
        from .engines import engine_blocks

        options, _ = super().record(technique, p_fit, ids)
        return options, {f"id{k}": engine_blocks(albedo=p_fit["albedo"][k - 1], d_mm=p_fit["d_mm"][k - 1])
                         for k in ids}


class _SeparableFit(_AbstractFit):
    build = {"interpolation": "linear"}

    def start(self, material, count):
        if isinstance(material, BurleyMaterial):
            material = _two_gaussian_from_burley(material, count)
        if not isinstance(material, TwoGaussianMaterial):
            raise TypeError("technique 'separable' starts from a TwoGaussianMaterial or a BurleyMaterial, got "
                            f"{type(material).__name__}")
        return ({"logit_w": _logit(_rows(material.w, count, "w")),
                 "log_sigma_near_mm": _log(_rows(material.sigma_near_mm, count, "sigma_near_mm")),
                 "log_sigma_far_mm": _log(_rows(material.sigma_far_mm, count, "sigma_far_mm"))},
                _rows(material.albedo, count, "albedo"))

    def natural(self, y, albedo, xp):
        return {"albedo": albedo, "w": 1 / (1 + xp.exp(-y["logit_w"])), "sigma_near_mm": xp.exp(y["log_sigma_near_mm"]),
                "sigma_far_mm": xp.exp(y["log_sigma_far_mm"])}

    def material(self, p):
        return TwoGaussianMaterial(p["albedo"], p["w"], p["sigma_near_mm"], p["sigma_far_mm"])

    def beyond_edge(self, material, distance_px, px_per_mm):
        """The separable kernel is a(x) a(y) with a the two-Gaussian mixture: the share beyond x is
        ``w Q(x / s_near) + (1 - w) Q(x / s_far)``, Q the standard normal tail."""
        from scipy.special import erfc

        def q(sigma_mm):
            s = np.asarray(sigma_mm, np.float64) * px_per_mm
            with np.errstate(divide="ignore", invalid="ignore"):
                return np.where(s > 0, 0.5 * erfc(distance_px / (np.sqrt(2) * np.where(s > 0, s, 1.0))), 0.0)

        w = np.asarray(material["w"], np.float64)
        return w * q(material["sigma_near_mm"]) + (1 - w) * q(material["sigma_far_mm"])


class _TranslucencyFit(_AbstractFit):
    def start(self, material, count):
        if isinstance(material, STAParams):  # the albedo: white where the buffers carry none
            material = (material, np.ones(3))
        if not (isinstance(material, tuple) and len(material) == 2 and isinstance(material[0], STAParams)):
            raise TypeError("technique 'sta' starts from STAParams or (STAParams, albedo (3,) or (M, 3))")
        params, alb = material
        one = lambda v: np.broadcast_to(np.asarray(v, np.float64), (count,)).copy()
        return ({"log_distortion": _log(one(params.distortion)), "log_power": _log(one(params.power)),
                 "log_scale": _log(_rows(params.scale, count, "scale")),
                 "log_ambient": _log(_rows(params.ambient, count, "ambient")),
                 "log_thickness_mm": _log(_rows(params.thickness_mm, count, "thickness_mm"))},
                _rows(alb, count, "albedo"))

    def material(self, p):
        return [STAParams(distortion=p["distortion"][k], power=p["power"][k], scale=p["scale"][k],
                          ambient=p["ambient"][k], thickness_mm=p["thickness_mm"][k])
                for k in range(p["scale"].shape[0])]

    def render(self, technique, frame, p):
        out = frame.buffers.irradiance
        with_albedo = technique.replace(albedo=p["albedo"])
        for k, params in enumerate(self.material(p)):  # STA parameters are one set per call: one pass per id
            o = with_albedo(frame.buffers, params, frame.camera)
            out = jnp.where((frame.ids == k + 1)[..., None], o, out)
        return out

    def record(self, technique, p_fit, ids):
        light = technique.light
        return ({"thickness": technique.thickness, "light_direction": np.asarray(light.direction).tolist(),
                 "light_colour": np.asarray(light.colour).tolist()}, None)


def _fits():
    from ._techniques import Burley, Separable, Translucency

    return {Burley: _BurleyFit(), Separable: _SeparableFit(), Translucency: _TranslucencyFit()}


# the fit of each technique class that can be fitted to a render
_FITS: dict[type, _AbstractFit] = _fits()
# the fit that owns a material's kernel (the start of a held-pixel score; edge_loss)
_FITS_BY_MATERIAL = {BurleyMaterial: next(f for f in _FITS.values() if isinstance(f, _BurleyFit)),
                     TwoGaussianMaterial: next(f for f in _FITS.values() if isinstance(f, _SeparableFit))}


def _natural(fit: _AbstractFit, y: Mapping[str, Any], albedo) -> dict[str, Any]:
    """Natural parameters from unconstrained ones (works on traced arrays and on NumPy)."""
    xp = jnp if any(isinstance(v, jax.Array) for v in y.values()) else np
    a = 1 / (1 + xp.exp(-y["logit_albedo"])) if "logit_albedo" in y else albedo
    return fit.natural(y, a, xp)


# ------------------------------------------------------------------------------------------------------------------
# which pixels are scored: those whose kernel the frame holds
# ------------------------------------------------------------------------------------------------------------------


def _kernel_rows(material) -> tuple[_AbstractFit | None, dict[str, np.ndarray]]:
    """The fit whose kernel ``material`` is, and its kernel parameters as ``(M, 3)`` float64 tables."""
    if isinstance(material, BurleyMaterial):
        return _FITS_BY_MATERIAL[BurleyMaterial], {"d_mm": np.asarray(material.d_mm, np.float64).reshape(-1, 3)}
    if isinstance(material, TwoGaussianMaterial):
        names = ("w", "sigma_near_mm", "sigma_far_mm")
        return _FITS_BY_MATERIAL[TwoGaussianMaterial], {
            n: np.asarray(getattr(material, n), np.float64).reshape(-1, 3) for n in names}
    return None, {}


def edge_loss(distance_px, material, rows, px_per_mm) -> np.ndarray:
    """Host side: the share of a pixel's kernel beyond a straight frame edge ``distance_px`` away, the largest over
    channels, shape of ``distance_px``. ``rows``: each pixel's material row (id - 1), ``px_per_mm``: its mm -> px
    factor at the pixel's depth. A ``BurleyMaterial``'s kernel is the Burley profile (its 1D marginal by K0
    integrals), a ``TwoGaussianMaterial``'s the separable two-Gaussian (normal tails); a material of no kernel
    (STA's) loses nothing: 0."""
    fit, table = _kernel_rows(material)
    if fit is None:
        return np.zeros(np.shape(distance_px))
    rows = np.asarray(rows)
    picked = {n: t[np.clip(rows, 0, t.shape[0] - 1)] for n, t in table.items()}  # (..., 3) per pixel
    x = np.asarray(distance_px, np.float64)[..., None]  # (..., 1) against (..., 3) channels
    loss = fit.beyond_edge(picked, x, np.asarray(px_per_mm, np.float64)[..., None])
    return np.asarray(loss).max(axis=-1)


def held_mask(frame: MatchFrame, material, *, held_fraction: float = HELD_FRACTION) -> np.ndarray:
    """Host side: ``(H, W)`` bool, the SSS pixels of ``frame`` whose kernel (``material``'s, at the pixel's own
    depth) the frame holds: at least ``held_fraction`` of its energy inside the frame, the shares beyond the four
    edges (``edge_loss``) summed (a bound: a corner's share counts twice)."""
    if not (0.0 < held_fraction < 1.0):
        raise ValueError(f"held_fraction must lie in (0, 1), got {held_fraction}")
    ids = frame.material_id
    h, w = ids.shape
    depth = np.asarray(frame.buffers.depth, np.float64)
    sss = ids > 0
    safe = np.where(sss & surface_mask(depth), depth, np.inf)
    px_per_mm = float(frame.camera.focal_px) / (safe * float(frame.camera.mm_per_unit))
    rows = np.maximum(ids - 1, 0)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    lost = sum(edge_loss(dist, material, rows, px_per_mm) for dist in (xs + 0.5, w - xs - 0.5, ys + 0.5, h - ys - 0.5))
    return sss & (1.0 - lost >= held_fraction)


def _scored_ids(frame: MatchFrame, material, score: str, held_fraction: float) -> np.ndarray:
    """The id map of the pixels scored: the frame's own (``"all"``), or 0 where the kernel is not held."""
    if score == "all":
        return frame.material_id
    return np.where(held_mask(frame, material, held_fraction=held_fraction), frame.material_id, 0).astype(np.int32)


# ------------------------------------------------------------------------------------------------------------------
# the problem: rendering and the residual
# ------------------------------------------------------------------------------------------------------------------


class _FrameData(eqx.Module):
    buffers: Buffers
    camera: Camera
    truth: jax.Array  # (H, W, 3)
    weight: jax.Array  # (H, W): 1 / ||truth_k|| (pooled over the fitted frames) on id k, 0 elsewhere
    scale: jax.Array  # (H, W): the Huber unit, mean truth of the pixel's material (1 where no SSS)
    ids: jax.Array  # (H, W) int32
    seed: Any = None  # a seeded technique's seed for this frame (uint32, as `apply` mixes it), None: no seed


class _Problem(eqx.Module):
    frames: tuple
    albedo: jax.Array  # (M, 3): used where the albedo is not fitted
    gain: jax.Array  # () constant factor on the residual: puts J^T J near 1 for the solver's first damping
    technique: Any  # the technique object (its options; the STA's light and thickness)
    fit: _AbstractFit = eqx.field(static=True)
    loss: str = eqx.field(static=True)
    huber_delta: float = eqx.field(static=True)


def _render(problem: _Problem, frame: _FrameData, y) -> jax.Array:
    y = jax.tree_util.tree_map(lambda v: jnp.asarray(v, problem.albedo.dtype), y)
    technique = problem.technique if frame.seed is None else _with_seed(problem.technique, frame.seed)
    return problem.fit.render(technique, frame, _natural(problem.fit, y, problem.albedo))


def _huber_residual(e: jax.Array, delta: float) -> jax.Array:
    """``sign(e) sqrt(2 huber_delta(e))``: its square is twice the Huber loss, so least squares minimises Huber.
    The double ``where`` keeps the gradient finite at e = 0."""
    a = jnp.abs(e)
    big = a > delta
    safe = jnp.where(big, a, 2 * delta)
    return jnp.where(big, jnp.sign(e) * jnp.sqrt(2 * delta * safe - delta**2), e)


def _residual(y, problem: _Problem):
    parts = []
    for frame in problem.frames:
        out = _render(problem, frame, y)
        e = (out - frame.truth) / frame.scale[..., None]
        if problem.loss == "huber":
            e = _huber_residual(e, problem.huber_delta)
        parts.append((e * (problem.gain * frame.scale * frame.weight)[..., None]).reshape(-1))
    return jnp.concatenate(parts)


@eqx.filter_jit
def _render_jit(problem: _Problem, frame: _FrameData, y):
    return _render(problem, frame, y)


def _frame_seed(technique, frame: MatchFrame) -> int | None:
    """The seed ``apply`` renders ``frame`` with: the technique's mixed with the frame's number; None: no seed."""
    return frame_seed(int(np.asarray(technique.seed)), frame.number) if _has_seed(technique) else None


def _frame_data(frame: MatchFrame, norms: Mapping[int, float], means: Mapping[int, float], dtype, technique,
                scored: np.ndarray | None = None) -> _FrameData:
    ids = frame.material_id if scored is None else scored  # the weights: the scored pixels only
    seed = _frame_seed(technique, frame)
    seed = None if seed is None else np.uint32(seed)
    weight = np.zeros(ids.shape, np.float64)
    scale = np.ones(ids.shape, np.float64)
    for k, n in norms.items():
        weight[ids == k] = 1.0 / n if n > 0 else 0.0
        scale[ids == k] = means[k] if means[k] > 0 else 1.0
    b = jax.tree_util.tree_map(lambda a: jnp.asarray(a, dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a,
                               frame.buffers)
    return _FrameData(b, Camera(jnp.asarray(frame.camera.focal_px, dtype), jnp.asarray(frame.camera.mm_per_unit, dtype),
                                frame.camera.principal_point),
                      jnp.asarray(frame.truth, dtype), jnp.asarray(weight, dtype), jnp.asarray(scale, dtype),
                      jnp.asarray(frame.material_id, jnp.int32), seed)


def _pooled_stats(frames: Sequence[MatchFrame], ids: Sequence[int],
                  scored: Sequence[np.ndarray] | None = None) -> tuple[dict[int, float], dict[int, float]]:
    norms, means = {}, {}
    scored = [f.material_id for f in frames] if scored is None else scored
    for k in ids:
        sq, total, count = 0.0, 0.0, 0
        for f, m in zip(frames, scored):
            t = f.truth[m == k].astype(np.float64)
            sq += float(np.sum(t**2))
            total += float(np.sum(t))
            count += t.size
        norms[k] = math.sqrt(sq)
        means[k] = total / count if count else 0.0
    return norms, means


# ------------------------------------------------------------------------------------------------------------------
# errors
# ------------------------------------------------------------------------------------------------------------------


def _errors(frames: Sequence[MatchFrame], outputs: Sequence[np.ndarray], ids: Sequence[int],
            scored: Sequence[np.ndarray] | None = None) -> dict[str, Any]:
    """rel_l2 per material id and over all SSS pixels (``scored``: over these id maps' pixels instead), pooled over
    ``frames`` and per frame (NumPy, float64)."""
    scored = [f.material_id for f in frames] if scored is None else scored

    def rel(pairs):
        num = sum(float(np.sum((o - t) ** 2)) for o, t in pairs)
        den = sum(float(np.sum(t**2)) for _, t in pairs)
        return math.sqrt(num / den) if den > 0 else None

    def groups(f, out, ids_map):
        o, t = out.astype(np.float64), f.truth.astype(np.float64)
        g = {"all": (o[ids_map > 0], t[ids_map > 0])}
        for k in ids:
            m = ids_map == k
            if m.any():
                g[f"id{k}"] = (o[m], t[m])
        return g

    per = [groups(f, o, m) for f, o, m in zip(frames, outputs, scored)]
    keys = ["all"] + [f"id{k}" for k in ids]
    pooled = {k: rel([g[k] for g in per if k in g]) for k in keys}
    return {"pooled": {k: v for k, v in pooled.items() if v is not None},
            "per_frame": [{"frame": f.name, **{k: rel([g[k]]) for k in keys if k in g}} for f, g in zip(frames, per)]}


# ------------------------------------------------------------------------------------------------------------------
# the result
# ------------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class MatchResult:
    """The outcome of ``match_render``.

    ``material``: the fitted material (``BurleyMaterial`` / ``TwoGaussianMaterial`` with one row per material id
    1..M, or for ``sta`` a list of ``STAParams`` per id and the albedo in ``parameters``); ``parameters`` and
    ``start``: ``{"id<k>": {name: values}}`` in natural units (mm, albedo in [0, 1]); ``errors``: ``{"fitted",
    "holdout"}`` each ``{"before": ..., "after": ...}`` as ``_errors`` gives (``holdout`` None without held-back
    frames); ``solver``: name, result (``optx.RESULTS`` name and message), iterations, seconds; ``engines``:
    ``{"id<k>": engine_blocks(...)}`` for a Burley fit (None otherwise); ``images``: per frame the truth, before
    and after renders and the id map (host arrays, for the report; not in ``to_json``); ``scored``: which pixels
    the fit scored (``rule``, ``score``, ``held_fraction``, per frame ``{"frame", "role", "sss_pixels",
    "scored_pixels", "per_id": {"id<k>": [scored, of]}}``) and ``errors[role]["scored"]``, the errors before and
    after on them; ``score_masks``: per frame (fitted, then held back) its ``(H, W)`` bool mask (not in
    ``to_json``)."""

    technique: str
    material: Any
    parameters: dict
    start: dict
    ids: tuple
    options: dict
    loss: dict
    solver: dict
    errors: dict
    engines: dict | None
    images: tuple = dataclasses.field(repr=False, default=())
    scored: dict | None = None
    score_masks: tuple = dataclasses.field(repr=False, default=())

    def to_json(self) -> dict[str, Any]:
        return {"technique": self.technique, "options": self.options, "material_ids": list(self.ids),
                "start": self.start, "fitted": self.parameters, "metric": METRIC, "loss": self.loss,
                "solver": self.solver, "errors": self.errors, "engines": self.engines, "scored": self.scored}


def _result_name(result) -> tuple[str, str]:
    import optimistix as optx

    for name in ("successful", "max_steps_reached", "nonlinear_max_steps_reached", "nonlinear_divergence",
                 "nonfinite", "singular", "breakdown", "stagnation", "nonfinite_input"):
        item = getattr(optx.RESULTS, name, None)
        if item is not None and bool(result == item):
            return name, str(optx.RESULTS[result]).strip()
    return "unknown", str(optx.RESULTS[result]).strip()


def _fit_technique(technique: str | AbstractTechnique, options: Mapping[str, Any] | None = None,
                   **available) -> tuple[AbstractTechnique, _AbstractFit]:
    """The technique object to fit and its fit: ``technique`` itself, or the class registered under that name built
    with the fit's own options, those of ``available`` it has fields for, and ``options`` (the caller's, over
    both)."""
    from ._techniques import TECHNIQUES

    names = [cls.name for cls in _FITS]
    if not isinstance(technique, AbstractTechnique):
        cls = TECHNIQUES.get(technique) if isinstance(technique, str) else None
        if cls not in _FITS:
            raise ValueError(f"unknown technique {technique!r}; valid techniques to fit: {', '.join(names)}")
        fields = {f.name: f for f in dataclasses.fields(cls)}
        given = dict(options or {})
        unknown = sorted(set(given) - set(fields))
        if unknown:
            raise ValueError(f"technique {technique!r} has no option(s) {', '.join(unknown)}")
        options = {k: v for k, v in available.items() if k in fields and v is not None}
        missing = [n for n, f in fields.items() if n not in options and f.default is dataclasses.MISSING
                   and f.default_factory is dataclasses.MISSING]
        if missing:
            raise ValueError(f"technique {technique!r} needs {', '.join(f'{n}=' for n in missing)}"
                             "DirectionalLight(direction, colour)")
        technique = cls(**{**_FITS[cls].build, **options, **given})
    if type(technique) not in _FITS:
        raise ValueError(f"technique {technique.name!r} cannot be fitted; valid techniques to fit: {', '.join(names)}")
    return technique, _FITS[type(technique)]


def _table(p: Mapping[str, Any], ids: Sequence[int]) -> dict[str, dict[str, Any]]:
    return {f"id{k}": {name: np.asarray(v)[k - 1].tolist() for name, v in p.items()} for k in ids}


def _pass_albedo(frames: Sequence[MatchFrame], ids: Sequence[int], albedo: np.ndarray) -> np.ndarray:
    """``albedo`` (one row per id 1..M) with each fitted id's row the mean of the frames' albedo passes (clipped
    to [0, 1], as the techniques read it) over that id's pixels."""
    out = np.array(albedo, np.float64, copy=True).reshape(-1, 3)
    for k in ids:
        pixels = np.concatenate([np.clip(np.asarray(f.buffers.albedo, np.float64), 0, 1)[np.asarray(f.material_id) == k]
                                 for f in frames])
        if pixels.size and out.shape[0] >= k:
            out[k - 1] = pixels.mean(axis=0)
    return out


def match_render(
    frames: MatchFrame | Sequence[MatchFrame],
    material,
    *,
    technique: str | AbstractTechnique = "burley",
    holdout: Sequence[MatchFrame] = (),
    samples: int = 32,
    taps: int = 25,
    light: DirectionalLight | None = None,
    thickness: float | None = None,
    fit_albedo: bool = False,
    loss: str = "huber",
    huber_delta: float = 0.5,
    max_steps: int = 20,
    rtol: float = 1e-3,
    atol: float = 1e-6,
    gain: float = 100.0,
    technique_options: Mapping[str, Mapping[str, Any]] | None = None,
    score: str = "held",
    held_fraction: float = HELD_FRACTION,
) -> MatchResult:
    """Fit ``technique``'s material per material id so its output on ``frames`` matches their truth renders.

    ``technique``: a name of ``MATCH_TECHNIQUES``, built with ``samples``/``taps``/``light``/``thickness`` where it
    has such an option, or a technique object (``sj.Burley(samples=16)``, ``sj.Translucency(light)``), fitted with
    its own options.

    ``material``: the start, one row for every id or one per id 1..M: a ``BurleyMaterial`` (``burley``; for
    ``separable`` it is turned into the two-Gaussian kernel by the profile-space fit), a ``TwoGaussianMaterial``
    (``separable``) or ``(STAParams, albedo (3,) or (M, 3))`` (``sta``, which also needs ``light`` and takes
    ``thickness`` in scene units where frames carry none). ``samples`` (Burley) and ``taps`` (separable) are the
    technique's sample counts: the fit is for that count. ``loss``: ``"huber"`` (``huber_delta`` in units of the
    material's mean truth value) or ``"l2"``. ``holdout``: frames measured before and after, not fitted.
    ``technique_options``: ``{technique name: {option: value}}``, further options of the technique built from its
    name (``{"burley": {"border": "leaves"}}``; what ``sss-jax fit --render`` passes from its flags).
    Solver: optimistix Levenberg–Marquardt (``rtol``, ``atol``, ``max_steps``), ``throw=False``.
    ``score``: ``"held"`` (default) fits and scores only the SSS pixels whose starting kernel the frame holds to
    ``held_fraction`` (``held_mask``: d is not bent to make up for light lost beyond the frame), ``"all"`` every SSS
    pixel; ``MatchResult.scored`` says which. The technique's own ``border`` (an option of the object) decides how
    its kernel meets the frame in the render; the score decides which pixels count.
    """
    import optimistix as optx

    frames = [frames] if isinstance(frames, MatchFrame) else list(frames)
    holdout = list(holdout)
    if not frames:
        raise ValueError("match_render needs at least one frame to fit")
    if loss not in MATCH_LOSSES:
        raise ValueError(f"unknown loss {loss!r}; valid losses: {', '.join(MATCH_LOSSES)}")
    if not (huber_delta > 0):
        raise ValueError(f"huber_delta must be > 0, got {huber_delta}")
    if score not in MATCH_SCORES:
        raise ValueError(f"unknown score {score!r}; valid scores: {', '.join(MATCH_SCORES)}")
    if not (0.0 < held_fraction < 1.0):
        raise ValueError(f"held_fraction must lie in (0, 1), got {held_fraction}")
    samples = check_host_count(samples, "samples")
    _check_taps(taps)
    max_steps = check_host_count(max_steps, "max_steps")
    check_host_range(gain, "gain", low_open=True)  # gain 0 "succeeded" without moving: no step is ever taken
    check_host_range(rtol, "rtol")
    check_host_range(atol, "atol")
    named = technique if isinstance(technique, str) else None
    given = dict((technique_options or {}).get(named, {})) if named is not None else {}
    if technique_options and named is None:
        raise ValueError("technique_options are for a technique given by name; a technique object has its own")
    technique, fit = _fit_technique(technique, given, samples=int(samples), taps=int(taps), light=light,
                                    thickness=None if thickness is None else float(thickness))
    for f in frames + holdout:
        if not isinstance(f, MatchFrame):
            raise TypeError(f"frames must be MatchFrame (match_frame / load_match_frame), got {type(f).__name__}")
    ids = sorted({int(k) for f in frames for k in np.unique(f.material_id) if k > 0})
    count = max(ids)
    for f in holdout:
        extra = sorted({int(k) for k in np.unique(f.material_id) if k > 0} - set(ids))
        if extra:
            raise ValueError(f"held-back frame {f.name} has material id(s) {extra} that no fitted frame has: "
                             "nothing is fitted for them")
    y0, albedo = fit.start(material, count)
    with_pass = [f.name for f in frames + holdout if f.buffers.albedo is not None]
    if fit_albedo and with_pass:
        raise ValueError(f"fit_albedo: {', '.join(with_pass)} carry an albedo pass, which decides the albedo wherever "
                         "it is given, so the material's albedo cannot be fitted; load the frames with "
                         "use_albedo_pass=False (what `sss-jax fit --fit-albedo` does)")
    if fit_albedo:
        y0["logit_albedo"] = _logit(albedo)
    # the kernel whose reach decides the scored pixels: the start's (separable from Burley: its two-Gaussian)
    kernel = fit.material(_natural(fit, y0, albedo))
    scored_fit = [_scored_ids(f, kernel, score, held_fraction) for f in frames]
    scored_hold = [_scored_ids(f, kernel, score, held_fraction) for f in holdout]
    unscored = [k for k in ids if not any(np.any(m == k) for m in scored_fit)]
    if unscored:
        raise ValueError(f"{', '.join(f.name for f in frames)}: no pixel of material id(s) {unscored} holds "
                         f"{held_fraction:g} of its kernel's energy inside the frame: nothing to score "
                         "(score='all', --score all, scores every SSS pixel)")
    # one dtype for parameters and images (lineax wants the Jacobian's input and output to agree): JAX's default
    # float, float32 unless x64 is on
    dtype = jnp.result_type(float)
    norms, means = _pooled_stats(frames, ids, scored_fit)
    data = tuple(_frame_data(f, norms, means, dtype, technique, m) for f, m in zip(frames, scored_fit))
    problem = _Problem(data, jnp.asarray(albedo, dtype), jnp.asarray(gain, dtype), technique, fit, loss,
                       float(huber_delta))
    y0 = {k: jnp.asarray(v, dtype) for k, v in y0.items()}

    t0 = time.perf_counter()
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    sol = optx.least_squares(_residual, solver, y0, args=problem, max_steps=int(max_steps), throw=False)
    y = jax.tree_util.tree_map(lambda v: v.block_until_ready(), sol.value)
    seconds = time.perf_counter() - t0
    name, message = _result_name(sol.result)
    if name != "successful" and not all(bool(jnp.all(jnp.isfinite(v))) for v in y.values()):
        y = y0  # a diverged solve keeps the start; the result code says so

    # errors, before and after, in the plain metric, on fitted and held-back frames (same dense pass as the fit)
    def run(fs, params):
        ns, ms = _pooled_stats(fs, ids)
        return [np.asarray(_render_jit(problem, _frame_data(f, ns, ms, dtype, technique), params)) for f in fs]

    before, after = run(frames, y0), run(frames, y)
    errors = {"fitted": {"frames": [f.name for f in frames], "before": _errors(frames, before, ids),
                         "after": _errors(frames, after, ids),
                         "scored": {"before": _errors(frames, before, ids, scored_fit),
                                    "after": _errors(frames, after, ids, scored_fit)}}, "holdout": None}
    images = [(f.name, "fitted", f.truth, b, a, f.material_id) for f, b, a in zip(frames, before, after)]
    if holdout:
        hb, ha = run(holdout, y0), run(holdout, y)
        errors["holdout"] = {"frames": [f.name for f in holdout], "before": _errors(holdout, hb, ids),
                             "after": _errors(holdout, ha, ids),
                             "scored": {"before": _errors(holdout, hb, ids, scored_hold),
                                        "after": _errors(holdout, ha, ids, scored_hold)}}
        images += [(f.name, "holdout", f.truth, b, a, f.material_id) for f, b, a in zip(holdout, hb, ha)]

    host = lambda yy: {k: np.asarray(v, np.float64) for k, v in yy.items()}
    p_start = _natural(fit, host(y0), np.asarray(albedo))
    p_fit = _natural(fit, host(y), np.asarray(albedo))
    albedo_from = "material"
    if len(with_pass) == len(frames + holdout):
        # the albedo pass rendered every frame, not the material's albedo: the albedo reported (and the engines'
        # blocks converted with) is the pass's mean over each id's pixels of the fitted frames
        p_start["albedo"] = p_fit["albedo"] = _pass_albedo(frames, ids, np.asarray(p_fit["albedo"]))
        albedo_from = "albedo pass (mean over each id's pixels of the fitted frames)"
    fitted = fit.material({k: jnp.asarray(v, dtype) for k, v in p_fit.items()})
    options, engines = fit.record(technique, p_fit, ids)
    options.update({k: v if isinstance(v, (str, int, float, bool, type(None))) else str(v) for k, v in given.items()})
    options["fit_albedo"] = bool(fit_albedo)
    options["albedo_from"] = albedo_from
    if _has_seed(technique):  # each frame's, as `apply` renders it: the technique's seed mixed with its number
        options["frame_seeds"] = {f.name: _frame_seed(technique, f) for f in frames + holdout}
    if getattr(technique, "border", None) is not None:
        options["border"] = technique.border
    held_rule = f"SSS pixels holding >= {held_fraction:g} of the starting kernel's energy inside the frame"
    rule = ("every SSS pixel" if score == "all" else held_rule if _kernel_rows(kernel)[0] is not None else
            "every SSS pixel (the technique's kernel does not reach past the frame)")
    scored = {"rule": rule, "score": score, "held_fraction": float(held_fraction), "frames": [
        {"frame": f.name, "role": role, "sss_pixels": int(np.count_nonzero(f.material_id > 0)),
         "scored_pixels": int(np.count_nonzero(m > 0)),
         "per_id": {f"id{k}": [int(np.count_nonzero(m == k)), int(np.count_nonzero(f.material_id == k))] for k in ids}}
        for role, fs, ms in (("fitted", frames, scored_fit), ("holdout", holdout, scored_hold))
        for f, m in zip(fs, ms)]}
    loss_info = {"name": loss, "note": "plain least squares on rel_l2 per material" if loss == "l2" else
                 "Huber on each pixel's residual in units of its material's mean truth value (quadratic up to "
                 "huber_delta, linear beyond), against the truth as given (not denoised)"}
    if loss == "huber":
        loss_info["huber_delta"] = float(huber_delta)
    return MatchResult(
        technique=technique.name, material=fitted, parameters=_table(p_fit, ids),
        start=_table(p_start, ids), ids=tuple(ids), options=options, loss=loss_info,
        solver={"name": "optimistix.LevenbergMarquardt", "rtol": rtol, "atol": atol, "max_steps": int(max_steps),
                "result": name, "message": message, "iterations": int(sol.stats["num_steps"]),
                "seconds": round(seconds, 3), "parameters": sorted(y0)},
        errors=errors, engines=engines, images=tuple(images), scored=scored,
        score_masks=tuple(m > 0 for m in scored_fit + scored_hold))


# ------------------------------------------------------------------------------------------------------------------
# the report section
# ------------------------------------------------------------------------------------------------------------------


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)
    return base64.b64encode(buf.getvalue()).decode()


def _frame_figure(name: str, role: str, truth, before, after, ids, exposure: float):
    from matplotlib.figure import Figure

    mask = ids > 0
    level = float(np.mean(truth[mask])) if mask.any() else 1.0
    err = lambda o: np.where(mask, np.sqrt(np.sum((o - truth) ** 2, axis=-1)) / max(level, 1e-12), 0.0)
    eb, ea = err(before), err(after)
    vmax = max(float(np.percentile(eb[mask], 99)) if mask.any() else 1.0, 1e-6)
    h, w = ids.shape
    fig = Figure(figsize=(3 * 2.6, 2 * 2.6 * h / w + 0.6), dpi=100)
    panels = [(truth, "truth"), (before, "before (start)"), (after, "after (fitted)")]
    for i, (img, title) in enumerate(panels):
        ax = fig.add_subplot(2, 3, i + 1)
        ax.imshow(display_transform(img, exposure=exposure), interpolation="nearest")
        ax.set_title(title, fontsize=8)
        ax.axis("off")
    ax = fig.add_subplot(2, 3, 4)
    ax.axis("off")
    ax.text(0.0, 0.5, f"{name}\n({role})", fontsize=8, va="center")
    error_axes = []
    for i, (e, title) in enumerate([(eb, "|before - truth|"), (ea, "|after - truth|")]):
        ax = fig.add_subplot(2, 3, 5 + i)
        im = ax.imshow(e, cmap="magma", vmin=0, vmax=vmax, interpolation="nearest")
        ax.set_title(f"{title} / mean truth", fontsize=8)
        ax.axis("off")
        error_axes.append(ax)
    fig.colorbar(im, ax=error_axes, fraction=0.03, pad=0.02)
    return fig


def _cell(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return ", ".join(_cell(x) for x in v)
    return html.escape(str(v))


def match_report_html(result: MatchResult, *, max_frames: int = 4, exposure: float = 0.0) -> str:
    """A self-contained HTML fragment (no ``<html>``; images embedded as base64 PNG) for a report section: the
    errors before and after, the fitted parameters beside the start, the solver's outcome, and per frame (up to
    ``max_frames``) the truth, the renders before and after, and their error maps."""
    check_host_count(max_frames, "max_frames")
    e = result.errors
    rows = []
    for role in ("fitted", "holdout"):
        if e.get(role) is None:
            continue
        for key, before in e[role]["before"]["pooled"].items():
            rows.append(f"<tr><td>{role} ({len(e[role]['frames'])} frame(s))</td><td>{key}</td>"
                        f"<td>{before:.4f}</td><td>{e[role]['after']['pooled'][key]:.4f}</td></tr>")
    opts = ", ".join(f"{k} {_cell(v)}" for k, v in result.options.items() if v is not None)
    parts = [f"<p>Technique <b>{html.escape(result.technique)}</b> ({opts}), "
             f"loss {html.escape(result.loss['name'])}, solver {html.escape(result.solver['name'])}: "
             f"{html.escape(result.solver['result'])} after {result.solver['iterations']} iterations, "
             f"{result.solver['seconds']:.1f} s. Metric: {html.escape(METRIC)}.</p>",
             "<table><tr><th>frames</th><th>pixels</th><th>rel_l2 before</th><th>rel_l2 after</th></tr>"
             + "".join(rows) + "</table>"]
    prow = []
    for k, fitted in result.parameters.items():
        for name, v in fitted.items():
            prow.append(f"<tr><td>{k}</td><td>{html.escape(name)}</td><td>{_cell(result.start[k][name])}</td>"
                        f"<td>{_cell(v)}</td></tr>")
    parts.append("<table><tr><th>material</th><th>parameter</th><th>start</th><th>fitted</th></tr>"
                 + "".join(prow) + "</table>")
    if result.engines:
        erow = []
        for k, blocks in result.engines.items():
            for engine, block in blocks.items():
                text = "; ".join(f"{a}: {_cell(b)}" for a, b in block.items())
                erow.append(f"<tr><td>{k}</td><td>{html.escape(engine)}</td><td style='text-align:left'>{text}"
                            "</td></tr>")
        parts.append("<table><tr><th>material</th><th>engine</th><th>parameters</th></tr>" + "".join(erow)
                     + "</table>")
    for name, role, truth, before, after, ids in result.images[:max_frames]:
        fig = _frame_figure(name, role, truth, before, after, ids, exposure)
        parts.append(f"<figure><img src='data:image/png;base64,{_png(fig)}' alt='{html.escape(name)}'>"
                     f"<figcaption>{html.escape(name)} ({role}): truth, before and after; error maps "
                     f"||out - truth||_RGB / mean truth on SSS pixels, one scale</figcaption></figure>")
    return "<div class='sss-jax-match'>" + "".join(parts) + "</div>"


def write_match_html(path: str | os.PathLike, result: MatchResult, **options) -> pathlib.Path:
    """A standalone HTML page holding ``match_report_html(result)``. Atomic; the path is checked before the page
    is built."""
    if not str(path).strip():
        raise SSSInputError("the page's path is empty")
    check_writable(path, create_dirs=False)
    title = f"sss-jax fit: {result.technique} matched to the truth render"
    page = ("<!doctype html><html><head><meta charset='utf-8'><title>" + html.escape(title) + "</title><style>"
            "body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}"
            "table{border-collapse:collapse;margin:1em 0;font-size:.9em}th,td{border:1px solid #ddd;"
            "padding:.3em .6em;text-align:right}th{background:#f4f4f4}figure{margin:1em 0}figure img{max-width:100%}"
            "figcaption{font-size:.85em;color:#555}</style></head><body><h1>" + html.escape(title) + "</h1>"
            + match_report_html(result, **options) + "</body></html>")
    return write_bytes_atomic(path, page.encode())
