"""What a caller hands the report: each frame's pictures and each technique's images and time.

The report computes nothing but metrics from these: simulations and timings are the caller's
(``sss_jax.evaluate_frames`` for EXR frames, ``sss_jax._demo`` for the built-in scene).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

__all__ = ["FrameImages", "TechniqueRun", "ReportData"]


def _rgb(name: str, a, shape=None) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim != 3 or a.shape[-1] != 3:
        raise ValueError(f"{name} must be an (H, W, 3) image, got shape {a.shape}")
    if shape is not None and a.shape[:2] != shape:
        raise ValueError(f"{name} is {a.shape[1]}x{a.shape[0]} but the frame is {shape[1]}x{shape[0]}")
    return a


@dataclasses.dataclass(frozen=True)
class FrameImages:
    """One frame: linear scene-referred RGB ``(H, W, 3)`` images and the ``(H, W)`` material ids.

    ``shaded``: the frame without subsurface scattering (albedo times irradiance), shown as the input.
    ``reference``: the dense reference. ``truth``: an offline render of the same view (e.g. Cycles' Combined) or
    None. ``material_id``: 0 where there is no SSS; the metrics use the pixels with id > 0 and finite depth
    (``mask``, computed by the caller; defaults to id > 0). ``window``: the input's windows, which the report's
    images keep (an overscan frame's lie over it in a compositor); ``header``: the input's header, whose colour
    primaries and camera they keep (``_io.CARRIED_ATTRIBUTES``)."""

    name: str
    shaded: np.ndarray
    reference: np.ndarray
    material_id: np.ndarray
    truth: np.ndarray | None = None
    mask: np.ndarray | None = None
    window: Any = None  # the input's data and display windows (``_io.Window``; an overscan margin), or None
    header: Any = None  # the input's header (``_io.Frame.metadata``): the images keep its colour primaries and camera

    def __post_init__(self):
        ref = _rgb(f"{self.name}: reference", self.reference)
        shape = ref.shape[:2]
        _rgb(f"{self.name}: shaded", self.shaded, shape)
        if self.truth is not None:
            _rgb(f"{self.name}: truth", self.truth, shape)
        ids = np.asarray(self.material_id)
        if ids.shape != shape:
            raise ValueError(f"{self.name}: material_id shape {ids.shape} does not match the frame's {shape}")
        mask = ids > 0 if self.mask is None else np.asarray(self.mask, bool) & (ids > 0)
        if mask.shape != shape:
            raise ValueError(f"{self.name}: mask shape {mask.shape} does not match the frame's {shape}")
        if not mask.any():
            raise ValueError(f"{self.name}: no pixel with subsurface scattering (material id > 0 and a surface)")
        object.__setattr__(self, "mask", mask)


@dataclasses.dataclass(frozen=True)
class TechniqueRun:
    """One technique at one count (taps or samples; None for STA and the engines' passes): ``images`` one per frame,
    in the frames' order, linear RGB ``(H, W, 3)``; ``ms_per_frame`` wall time per frame in milliseconds (None when
    not timed); ``options`` the technique's options that differ from its defaults."""

    technique: str
    count: int | None
    ms_per_frame: float | None
    images: tuple[np.ndarray, ...]
    options: dict[str, Any] = dataclasses.field(default_factory=dict)
    # whether the technique redistributes light (None: as the registry's class of ``technique`` says)
    conserves_energy: bool | None = None
    # what a pixel costs as the technique's shader executes it (``_cost.frame_cost``: samples, fetches, flops per SSS
    # pixel and frame), pooled over the frames; None where unknown
    cost_per_pixel: dict[str, Any] | None = None
    # told apart from another run of the same technique and count (its options, e.g. "quality=high"); "" if none
    tag: str = ""

    @property
    def adds_light(self) -> bool:
        """The technique adds light (the STA): the report keeps such runs apart from those that redistribute it."""
        if self.conserves_energy is not None:
            return not self.conserves_energy
        from .._techniques._registry import ENERGY_CONSERVING

        return not ENERGY_CONSERVING.get(self.technique, True)

    @property
    def label(self) -> str:
        return " ".join([self.technique] + ([str(self.count)] if self.count is not None else [])
                        + ([self.tag] if self.tag else []))


@dataclasses.dataclass(frozen=True)
class ReportData:
    """Everything one report shows. ``inputs``: one JSON-able dict per frame (path, size, layout, camera...);
    ``material`` and ``machine``: JSON-able dicts; ``reference_run``: the reference's own time (and, with a truth, its
    distance from it); ``notes``: lines of plain text shown under the summary (cache use, skipped techniques)."""

    frames: tuple[FrameImages, ...]
    runs: tuple[TechniqueRun, ...]
    inputs: list[dict[str, Any]]
    material: dict[str, Any]
    machine: dict[str, Any]
    title: str = "sss_jax error report"
    reference_run: TechniqueRun | None = None
    notes: tuple[str, ...] = ()
    exposure: float = 0.0

    def __post_init__(self):
        if not self.frames:
            raise ValueError("a report needs at least one frame")
        for run in (*self.runs, *([self.reference_run] if self.reference_run else [])):
            if len(run.images) != len(self.frames):
                raise ValueError(f"{run.label}: {len(run.images)} image(s) for {len(self.frames)} frame(s)")
            for frame, img in zip(self.frames, run.images):
                _rgb(f"{run.label} on {frame.name}", img, frame.reference.shape[:2])
