"""``Translucency`` (registry name ``"sta"``): back-light through thin parts as a technique object. It ADDS light.

The light and the thickness belong to the technique (fields), the medium to the material (``STAParams`` for the STA,
``BurleyMaterial`` or a preset's ``MediumMaterial`` for the physically based models): no ``(params, light)`` pair
poses as a material.
"""

from __future__ import annotations

import inspect
from typing import ClassVar

from jaxtyping import Array, Float

from .._custom_types import ParamLike
from .._materials import BurleyMaterial, DirectionalLight, STAParams
from .._scene import Buffers, Camera
from .._slab import MediumMaterial
from . import _translucency
from ._base import AbstractTechnique, built, call_options, default_of, option

_f = _translucency.translucency

# the material each model takes
_MODEL_MATERIALS: dict[str, tuple[type, ...]] = {"sta": (STAParams,), "thin": (BurleyMaterial,),
                                                 "slab": (BurleyMaterial, MediumMaterial)}


class Translucency(AbstractTechnique):
    """``albedo * (irradiance + transmitted back-light)`` on SSS pixels (``sss_jax.translucency``'s docstring holds
    the models). Does NOT conserve energy: the back-light through the thickness is added."""

    name: ClassVar[str] = "sta"
    conserves_energy: ClassVar[bool] = False
    material_type: ClassVar[tuple[type, ...]] = (STAParams, BurleyMaterial, MediumMaterial)

    light: DirectionalLight
    thickness: ParamLike | None = option(default_of(_f, "thickness"), "constant thickness in scene units where "
                                         "the buffers carry none (None: paper-thin)", static=False)
    albedo: ParamLike | None = option(default_of(_f, "albedo"), "surface albedo R,G,B in [0, 1] where the buffers "
                                      "carry none (model 'sta'; None: white)", static=False)
    model: str = option(default_of(_f, "model"), "the STA ('sta'), HDRP's thin-object transmission ('thin') or "
                        "slab transport ('slab')", choices=_translucency.TRANSLUCENCY_MODELS)

    @classmethod
    def accepts(cls, material, **options) -> bool:
        return isinstance(material, _MODEL_MATERIALS[options.get("model", default_of(_f, "model"))])

    def takes(self, material) -> bool:
        return isinstance(material, _MODEL_MATERIALS[self.model])

    def check_material(self, material) -> None:
        kinds = _MODEL_MATERIALS[self.model]
        if not isinstance(material, kinds):
            raise TypeError(f"sta (model={self.model!r}) needs a {' or '.join(k.__name__ for k in kinds)}, "
                            f"got {type(material).__name__}")

    def __call__(self, buffers: Buffers, material: STAParams | BurleyMaterial | MediumMaterial, camera: Camera, *,
                 origin: tuple[int, int] = (0, 0),
                 frame_shape: tuple[int, int] | None = None) -> Float[Array, "H W 3"]:
        if tuple(origin) != (0, 0) or frame_shape is not None:
            # a local pass, but the view ray of a pixel comes from its place relative to the principal point: a tile
            # sees the frame's principal point moved by its origin
            h, w = frame_shape if frame_shape is not None else buffers.depth.shape[-2:]
            cx, cy = camera.principal_point if camera.principal_point is not None else (w / 2, h / 2)
            camera = Camera(camera.focal_px, camera.mm_per_unit,
                            principal_point=(cx - int(origin[1]), cy - int(origin[0])))
        return _f(buffers, material, camera, self.light, **call_options(self, material))

    def reach_px(self, buffers: Buffers, material: STAParams | BurleyMaterial | MediumMaterial,
                 camera: Camera) -> int:
        """Local: 0 with a normal buffer; 1 where the normals come from depth (central differences)."""
        return 0 if buffers.normal is not None else 1


def translucency(buffers: Buffers, params: STAParams | BurleyMaterial | MediumMaterial, camera: Camera,
                 light: DirectionalLight, **options) -> Float[Array, "H W 3"]:
    return built(Translucency, options, (light,))(buffers, params, camera)


# the function's own docstring and signature (its options, their defaults): help() and inspect read them
translucency.__doc__ = _f.__doc__
translucency.__signature__ = inspect.signature(_f)
