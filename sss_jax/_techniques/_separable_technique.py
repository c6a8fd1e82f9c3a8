"""``Separable``: separable subsurface scattering (SSSS) as a technique object (``_separable`` computes)."""

from __future__ import annotations

import inspect
import math
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import SamplingWarning
from .._materials import BurleyMaterial, ProfileMaterial, TwoGaussianMaterial
from .._scene import Buffers, Camera
from . import _separable
from ._base import AbstractTechnique, built, call_options, default_of, option, tile_options
from ._common import ALBEDO_MODES, BORDERS, _material_rows, _sss_mask
from ._dispatch import impl_choices

_f = _separable.separable


def separable_sampling_warnings(buffers: Buffers, material, camera: Camera, *, taps: int,
                                min_footprint_px: float) -> list[Warning]:
    """Host side: the ``SamplingWarning``s a call on the whole of ``buffers`` raises
    (``_separable.sampling_messages``)."""
    return [SamplingWarning(m) for m in _separable.sampling_messages(
        buffers, material, camera, int(taps), float(min_footprint_px), tuple(buffers.depth.shape[-2:]))]


def kernel_reach_mm(material, taps: int) -> np.ndarray:
    """Host side: each material's kernel reach, its outermost tap's offset in mm, ``(M,)`` (float64): what decides
    the pass's footprint (a pixel whose reach in px is under ``min_footprint_px`` keeps its local shading) and its
    halo. Every pattern of n > 1 taps ends at +-1 of the reach (``unit_tap_offsets``): the 3-tap kernel has the
    outermost tap of any count (a count typed far too large, 200001: building its kernel took 50 s and 5.9 GB on a
    256x192 frame, before the batch's clamp cut it to 65 taps)."""
    kernels = material.separable_kernels(min(int(taps), 3), jax.dtypes.canonicalize_dtype(jnp.float64))
    return np.max(np.abs(np.asarray(kernels.offsets_mm, np.float64)), axis=-1)


class Separable(AbstractTechnique):
    """Jimenez et al.'s separable SSS, a horizontal then a vertical 1D pass (``sss_jax.separable``'s docstring holds
    the method, the options' meaning and their cost). Conserves energy: it redistributes light."""

    name: ClassVar[str] = "separable"
    conserves_energy: ClassVar[bool] = True
    count_option: ClassVar[str | None] = "taps"
    material_type: ClassVar[tuple[type, ...]] = (TwoGaussianMaterial, BurleyMaterial, ProfileMaterial)

    taps: int = option(default_of(_f, "taps"), "taps per 1D pass (odd)")
    albedo_mode: str = option(default_of(_f, "albedo_mode"), "where the albedo multiplies: after the scatter "
                              "('post') or its square root before and after ('pre_post')", choices=ALBEDO_MODES)
    follow_surface: bool = option(default_of(_f, "follow_surface"), "taps across a depth step count as the centre "
                                  "(light does not cross depth discontinuities)", choices=(True, False))
    interpolation: str = option(default_of(_f, "interpolation"), "how a tap fetches the irradiance",
                                choices=("linear", "nearest"))
    min_footprint_px: float = option(default_of(_f, "min_footprint_px"), "pixels whose 99%-energy radius is "
                                     "below this (px) keep their local shading; 0 disables that")
    scale_levels: int = option(default_of(_f, "scale_levels"), "reach levels of the banded formulation")
    impl: str = option(default_of(_f, "impl"), "the formulation ('auto': the fastest one with these options on "
                       "the backend)", choices=impl_choices("separable"))
    border: str = option(default_of(_f, "border"), "light reaching past the frame leaves ('leaves') or the "
                         "kernel is renormalised over the frame ('renormalise')", choices=BORDERS)

    def __check_init__(self):
        # checked when the object is made, not only when it runs (a bench or a batch builds its runs first)
        _separable.check_separable_counts(self.taps, self.scale_levels, self.min_footprint_px)

    def __call__(self, buffers: Buffers, material: TwoGaussianMaterial | BurleyMaterial | ProfileMaterial,
                 camera: Camera, *, origin: tuple[int, int] = (0, 0),
                 frame_shape: tuple[int, int] | None = None) -> Float[Array, "H W 3"]:
        options = call_options(self, material)
        return _f(buffers, material, camera, **options, **tile_options(_f, buffers, origin, frame_shape))

    def reach_px(self, buffers: Buffers, material: TwoGaussianMaterial | BurleyMaterial | ProfileMaterial,
                 camera: Camera) -> int:
        """The farthest tap: each material's kernel reach (its outermost tap, mm) projected at the nearest active
        pixel using it, plus the linear fetch's second pixel. The vertical pass reads, at most that far up or down,
        what the horizontal pass read at most that far along its row: the halo is the reach on every side. At most
        the frame's larger extent (a wider kernel is cut at the frame)."""
        self.check_material(material)
        valid = np.asarray(_sss_mask(buffers))
        if not valid.any():
            return 0
        reach_mm = kernel_reach_mm(material, int(self.taps))
        rows = np.asarray(_material_rows(buffers, reach_mm.shape[0]))
        depth = np.asarray(buffers.depth, np.float64)
        safe = np.where(valid, depth, np.inf)  # (valid: a surface, _sss_mask)
        px = reach_mm[rows] * float(camera.focal_px) / (safe * float(camera.mm_per_unit))
        active = valid & (px >= float(self.min_footprint_px)) & (px > 0)
        widest = float(np.max(px, where=active, initial=0.0))
        if widest <= 0:
            return 0
        reach = math.ceil(widest) + (1 if self.interpolation == "linear" else 0)
        return int(min(reach, max(buffers.depth.shape[-2:])))

    def check(self, buffers: Buffers, material: TwoGaussianMaterial | BurleyMaterial | ProfileMaterial,
              camera: Camera) -> list[Warning]:
        self.check_material(material)
        return separable_sampling_warnings(buffers, material, camera, taps=int(self.taps),
                                           min_footprint_px=float(self.min_footprint_px))


def separable(buffers: Buffers, material: TwoGaussianMaterial | BurleyMaterial | ProfileMaterial, camera: Camera, *,
              origin: tuple[int, int] = (0, 0), frame_shape: tuple[int, int] | None = None, **options) -> Float[Array, "H W 3"]:
    # origin/frame_shape place the buffer in the whole frame (tiles): arguments of the call, not options
    return built(Separable, options)(buffers, material, camera, origin=origin, frame_shape=frame_shape)


# the function's own docstring and signature (its options, their defaults): help() and inspect read them
separable.__doc__ = _f.__doc__
separable.__signature__ = inspect.signature(_f)
