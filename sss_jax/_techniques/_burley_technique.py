"""``Burley``: screen-space Christensen–Burley normalised diffusion as a technique object (``_burley`` computes)."""

from __future__ import annotations

import inspect
import math
from typing import ClassVar

import numpy as np
from jaxtyping import Array, Float

from .._errors import SamplingWarning
from .._materials import BurleyMaterial
from .._scene import Buffers, Camera
from . import _burley
from ._base import AbstractTechnique, built, call_options, default_of, frame_pieces, option, tile_options
from ._common import ALBEDO_MODES, BORDERS
from ._dispatch import impl_choices

_f = _burley.burley

# The rotation of frame k under seed s hashes s * 0x9E3779B9 + k * 0x85EBCA6B (uint32; _burley_spec.spiral_rotation):
# frame a + k under s is frame k under s + a * 0x85EBCA6B / 0x9E3779B9 (mod 2^32; the multiplier is odd, so it has
# an inverse). A run of K frames therefore splits into calls of fewer frames, each with its shifted seed, that give
# the same rotations (tests/test_batch.py checks the pieces against the whole call).
_SEED_STEP = (0x85EBCA6B * pow(0x9E3779B9, -1, 1 << 32)) & 0xFFFFFFFF
# samples a frame keeps at least when a long frame's samples are spread over frames (below that the spiral's
# stratification, not the count, would decide the error)
_SPREAD_MIN_SAMPLES = 64


def seed_of_frame(seed: int, first_frame: int) -> int:
    """The seed under which frame 0 turns the spiral as frame ``first_frame`` does under ``seed`` (and frame k as
    frame ``first_frame + k``)."""
    return (int(seed) + int(first_frame) * _SEED_STEP) & 0xFFFFFFFF


def burley_sampling_warnings(buffers: Buffers, material: BurleyMaterial, camera: Camera, *, samples: int,
                             frames: int, min_footprint_px: float) -> list[Warning]:
    """Host side: the ``SamplingWarning`` a channel much narrower than the widest one implies (the samples follow
    the widest channel's profile, so it sees only its innermost few), if any SSS pixel takes samples."""
    count, _ = _burley._burley_active(buffers, material, camera, float(min_footprint_px))
    if not count:
        return []
    worst = _burley.burley_channel_samples(material.d_mm, int(samples) * int(frames))
    if worst is None or worst[0] >= 4:
        return []
    n_eff, m, c = worst
    d = np.asarray(material.d_mm, np.float64).reshape(-1, 3)
    implied = min(1.0, 0.5 / math.sqrt(max(n_eff, 1e-9)))
    return [SamplingWarning(f"burley: channel {'RGB'[c]} of material {m + 1} (d {d[m, c]:.3g} mm, the widest "
                            f"{d[m].max():.3g} mm) gets {n_eff:.2g} of {samples * frames} samples within the radius "
                            f"holding 95% of its energy: its kernel is not represented (per-pixel error up to "
                            f"{implied:.2f} of an edge's contrast); more samples or frames")]


class Burley(AbstractTechnique):
    """Christensen–Burley normalised diffusion in one pass of golden-angle spiral samples (``sss_jax.burley``'s
    docstring holds the method, the options' meaning and their cost). Conserves energy: it redistributes light."""

    name: ClassVar[str] = "burley"
    conserves_energy: ClassVar[bool] = True
    sss_pixels_only: ClassVar[bool] = True
    count_option: ClassVar[str | None] = "samples"
    material_type: ClassVar[type] = BurleyMaterial

    samples: int = option(default_of(_f, "samples"), "spiral samples per pixel (per frame)")
    albedo_mode: str = option(default_of(_f, "albedo_mode"), "where the albedo multiplies: after the scatter "
                              "('post') or its square root before and after ('pre_post')", choices=ALBEDO_MODES)
    interpolation: str = option(default_of(_f, "interpolation"), "how a sample fetches the irradiance",
                                choices=("bilinear", "nearest"))
    min_footprint_px: float = option(default_of(_f, "min_footprint_px"), "pixels whose 99%-energy radius is "
                                     "below this (px) keep their local shading; 0 disables that")
    compact: bool | None = option(default_of(_f, "compact"), "compute only the active pixels, compacted (None: "
                                  "where that holds under half the frame)", choices=(None, True, False))
    impl: str = option(default_of(_f, "impl"), "the formulation ('auto': the fastest one with these options on "
                       "the backend)", choices=impl_choices("burley"))
    pattern: str = option(default_of(_f, "pattern"), "the spiral turned per pixel and frame ('rotated') or the "
                          "same for every pixel ('fixed')", choices=_burley.BURLEY_PATTERNS)
    frames: int = option(default_of(_f, "frames"), "frames averaged, each with its own rotations (converged TAA)")
    seed: int | Array = option(default_of(_f, "seed"), "seed of the rotations (e.g. the frame number); traced",
                               static=False)
    border: str = option(default_of(_f, "border"), "light reaching past the frame leaves ('leaves') or the "
                         "kernel is renormalised over the frame ('renormalise')", choices=BORDERS)

    def __check_init__(self):
        # checked when the object is made, not only when it runs: reach_px, pieces and spread (a batch's halos and
        # pieces) read them first
        _burley.check_burley_counts(self.samples, self.frames, self.min_footprint_px, self.seed)

    def __call__(self, buffers: Buffers, material: BurleyMaterial, camera: Camera, *,
                 origin: tuple[int, int] = (0, 0), frame_shape: tuple[int, int] | None = None,
                 keep: tuple[int, int, int, int] | None = None) -> Float[Array, "H W 3"]:
        """``keep``: ``burley``'s (the pixels a tile keeps: only they are computed)."""
        options = call_options(self, material)
        return _f(buffers, material, camera, **options, **tile_options(_f, buffers, origin, frame_shape), keep=keep)

    def reach_px(self, buffers: Buffers, material: BurleyMaterial, camera: Camera) -> int:
        """How far a pixel's fetches reach (``_burley_spec.burley_reach_px``: the farthest sample of the widest
        active profile, plus the bilinear fetch's second pixel; at most the frame's larger extent)."""
        return _burley.burley_halo_px(buffers, material, camera, samples=self.samples,
                                      min_footprint_px=self.min_footprint_px, interpolation=self.interpolation)

    def pieces(self, count: int) -> tuple[tuple["Burley", float], ...] | None:
        """The ``frames`` in about ``count`` groups of consecutive frames, each a call with fewer frames and the seed
        that gives it those frames' rotations (``seed_of_frame``), weighted by its share of the frames: the same
        pixels to rounding. ``None`` for one frame, and for the fixed spiral (its frame 0 is unturned whatever the
        seed, so a later group cannot start there)."""
        if self.pattern != "rotated":
            return None
        return frame_pieces(self, count, seed_of_frame)

    def spread(self, count: int) -> "Burley":
        """Samples moved into frames (halved per doubling of the frames, each frame its own rotation: the same
        samples per pixel, another sampling of the profile) until there are ``count`` frames, keeping at least 64
        samples a frame; itself for the fixed spiral or where the frames already suffice."""
        samples, frames = int(self.samples), int(self.frames)
        if self.pattern != "rotated" or frames >= count:
            return self
        q = 1
        while frames * q < count and samples // (2 * q) >= _SPREAD_MIN_SAMPLES:
            q *= 2
        return self if q == 1 else self.replace(samples=-(-samples // q), frames=frames * q)

    def check(self, buffers: Buffers, material: BurleyMaterial, camera: Camera) -> list[Warning]:
        self.check_material(material)
        return burley_sampling_warnings(buffers, material, camera, samples=int(self.samples),
                                        frames=int(self.frames), min_footprint_px=float(self.min_footprint_px))


def burley(buffers: Buffers, material: BurleyMaterial, camera: Camera, *,
           origin: tuple[int, int] = (0, 0), frame_shape: tuple[int, int] | None = None,
           keep: tuple[int, int, int, int] | None = None, **options) -> Float[Array, "H W 3"]:
    # origin/frame_shape place the buffer in the whole frame (tiles), keep names the pixels a tile keeps: arguments
    # of the call, not options
    return built(Burley, options)(buffers, material, camera, origin=origin, frame_shape=frame_shape, keep=keep)


# the function's own docstring and signature (its options, their defaults): help() and inspect read them
burley.__doc__ = _f.__doc__
burley.__signature__ = inspect.signature(_f)
