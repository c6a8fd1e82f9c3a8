"""Engines: one material in every engine's units. One final class per engine (one file each) under a shared
abstract base (``_base.AbstractEngine``), and a registry (``_registry.REGISTRY``) that ``convert``, presets' engine
blocks, ``engine_profile_error``, the report and ``sss-jax convert`` all go through. docs/engines.md has the formulas
and the source (file, version) of each."""

from ._base import AbstractEngine as AbstractEngine, Flag as Flag
from ._blender import (
    CURRENT_BLENDER as CURRENT_BLENDER,
    random_walk_medium as random_walk_medium,
    random_walk_single_scattering_albedo as random_walk_single_scattering_albedo,
)
from ._hdrp import srgb_decode as srgb_decode, srgb_encode as srgb_encode
from ._jimenez import jimenez_kernel as jimenez_kernel
from ._registry import (
    BLOCK_ENGINES as BLOCK_ENGINES,
    ENGINES as ENGINES,
    KERNELS as KERNELS,
    LOSSY as LOSSY,
    REGISTRY as REGISTRY,
    convert as convert,
    engine_blocks as engine_blocks,
    engine_errors_against as engine_errors_against,
    engine_marginals as engine_marginals,
    engine_profile_error as engine_profile_error,
    from_engine as from_engine,
    get_engine as get_engine,
    to_engine as to_engine,
)
