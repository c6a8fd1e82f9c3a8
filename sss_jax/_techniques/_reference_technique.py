"""``Reference``: the dense brute-force convolution used as ground truth, as a technique object."""

from __future__ import annotations

import inspect
from typing import ClassVar

from jaxtyping import Array, Float

from .._errors import ReferenceWindowWarning
from .._materials import BurleyMaterial, ProfileMaterial
from .._scene import Buffers, Camera
from . import _reference
from ._base import AbstractTechnique, built, call_options, default_of, option, tile_options
from ._common import ALBEDO_MODES, BORDERS

_f = _reference.reference


def reference_window_warnings(buffers: Buffers, material: BurleyMaterial | ProfileMaterial, camera: Camera, *,
                              radius_px: int) -> list[Warning]:
    """Host side: the ``ReferenceWindowWarning`` a window of ``radius_px`` holding under 99.9% of the profile's
    energy at the nearest SSS pixel implies."""
    held = _reference.reference_energy_held(buffers, material, camera, int(radius_px))
    if held >= 0.999:
        return []
    return [ReferenceWindowWarning(
        f"reference: the {radius_px}-px window holds {held:.1%} of the profile's energy at the nearest SSS pixel "
        f"(the frame needs {max(buffers.depth.shape[-2:]) - 1} px to hold all of it): the result misses the rest; "
        "pass a larger radius_px")]


class Reference(AbstractTechnique):
    """Ground truth: every pixel within the window contributes the exact mass of the profile over its footprint
    (``sss_jax.reference``'s docstring). Conserves energy: it redistributes light."""

    name: ClassVar[str] = "reference"
    conserves_energy: ClassVar[bool] = True
    material_type: ClassVar[tuple[type, ...]] = (BurleyMaterial, ProfileMaterial)

    radius_px: int | None = option(default_of(_f, "radius_px"), "window radius in px (None: the radius holding "
                                   "99.9% of the widest profile's energy at the nearest SSS pixel, at most 96)")
    albedo_mode: str = option(default_of(_f, "albedo_mode"), "where the albedo multiplies: after the scatter "
                              "('post') or its square root before and after ('pre_post')", choices=ALBEDO_MODES)
    near_subsamples: int = option(default_of(_f, "near_subsamples"), "midpoint-rule points per side for the "
                                  "pixels within two of the centre")
    border: str = option(default_of(_f, "border"), "light reaching past the frame leaves ('leaves') or the "
                         "kernel is renormalised over the frame ('renormalise')", choices=BORDERS)

    def __check_init__(self):
        # checked when the object is made: reach_px (a batch's halo) reads radius_px before any call
        _reference.check_reference_counts(self.radius_px, self.near_subsamples)

    def __call__(self, buffers: Buffers, material: BurleyMaterial | ProfileMaterial, camera: Camera, *,
                 origin: tuple[int, int] = (0, 0), frame_shape: tuple[int, int] | None = None,
                 keep: tuple[int, int, int, int] | None = None) -> Float[Array, "H W 3"]:
        """``keep``: ``reference``'s (the pixels a tile keeps: only they are computed)."""
        options = call_options(self, material)
        return _f(buffers, material, camera, **options, **tile_options(_f, buffers, origin, frame_shape), keep=keep)

    def window_px(self, buffers: Buffers, material: BurleyMaterial | ProfileMaterial, camera: Camera) -> int:
        """Host side: the window radius a call uses (``radius_px``, or the default for these buffers)."""
        if self.radius_px is not None:
            return int(self.radius_px)
        return _reference.reference_radius_px(buffers, material, camera)

    def reach_px(self, buffers: Buffers, material: BurleyMaterial | ProfileMaterial, camera: Camera) -> int:
        """The window: a pixel reads the pixels within ``window_px`` along each axis, none beyond."""
        self.check_material(material)
        return self.window_px(buffers, material, camera)

    def check(self, buffers: Buffers, material: BurleyMaterial | ProfileMaterial, camera: Camera) -> list[Warning]:
        self.check_material(material)
        return reference_window_warnings(buffers, material, camera, radius_px=self.window_px(buffers, material, camera))


def reference(buffers: Buffers, material: BurleyMaterial | ProfileMaterial, camera: Camera, *,
              origin: tuple[int, int] = (0, 0), frame_shape: tuple[int, int] | None = None,
              keep: tuple[int, int, int, int] | None = None, **options) -> Float[Array, "H W 3"]:
    # origin/frame_shape place the buffer in the whole frame (tiles), keep names the pixels a tile keeps: arguments
    # of the call, not options
    return built(Reference, options)(buffers, material, camera, origin=origin, frame_shape=frame_shape, keep=keep)


# the function's own docstring and signature (its options, their defaults): help() and inspect read them
reference.__doc__ = _f.__doc__
reference.__signature__ = inspect.signature(_f)
