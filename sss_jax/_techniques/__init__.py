"""The four screen-space techniques, each a jitted function of (buffers, material parameters, camera), one file each.

- ``translucency`` (STA, ``_translucency``): local, adds back-light through thickness. Does NOT conserve energy.
- ``separable`` (SSSS, ``_separable``): a horizontal then a vertical 1D pass, depth-aware ("follow the surface").
- ``burley`` (``_burley``): one pass of n golden-angle spiral samples of the Christensen–Burley profile, normalised.
- ``reference`` (``_reference``): dense, brute-force convolution with the exact profile integrated over each pixel.

``separable``, ``burley`` and ``reference`` redistribute light: each output pixel is a normalised weighted mean of
irradiance, so flat lighting stays flat and energy is conserved away from image and depth borders. What they share
(which pixels take part, the albedo split, checks under ``jit``) is in ``_common``. Lengths of materials are in mm,
depth in scene units, offsets in pixels via ``_units``.

Each technique is also an object (``_base.AbstractTechnique``; ``Burley``, ``Separable``, ``Translucency``,
``Reference``, one file each beside the technique, ``_registry.technique(name, **options)``): its options are fields,
and it answers for its material, energy conservation, reach in px and warnings; the functions are thin wrappers.

``separable`` and ``burley`` have one formulation per backend (``impl=``, ``_dispatch``): on a CPU the banded,
level-quantised and compacted passes in ``_separable``/``_burley``; elsewhere the whole-frame per-pixel gathers of
``_separable_gpu``/``_burley_gpu`` (no host round trip), also as Pallas kernels (``_pallas``).
"""

from ._burley import BURLEY_PATTERNS as BURLEY_PATTERNS
from ._burley import (
    burley_active_count as burley_active_count,
)
from ._burley import burley_channel_samples as burley_channel_samples
from ._burley import (
    compaction_capacity as compaction_capacity,
)
from ._burley import spiral_rotation as spiral_rotation
from ._burley import (
    weight_channel_count as weight_channel_count,
)
from ._common import ALBEDO_MODES as ALBEDO_MODES
from ._common import BORDERS as BORDERS
from ._common import MIN_FOOTPRINT_PX as MIN_FOOTPRINT_PX
from ._dispatch import IMPLS as IMPLS
from .._errors import SamplingWarning as SamplingWarning
from ._common import frame_energy_fraction as frame_energy_fraction
from .._errors import ReferenceWindowWarning as ReferenceWindowWarning
from ._reference import reference_energy_held as reference_energy_held
from ._reference import reference_radius_px as reference_radius_px
from ._registry import ENERGY_CONSERVING as ENERGY_CONSERVING
from ._registry import TECHNIQUES as TECHNIQUES
from ._registry import get_technique as get_technique
from ._registry import technique as technique
from ._base import AbstractTechnique as AbstractTechnique
from ._base import option as option
from ._burley_technique import Burley as Burley
from ._burley_technique import burley as burley
from ._reference_technique import Reference as Reference
from ._reference_technique import reference as reference
from ._separable_technique import Separable as Separable
from ._separable_technique import separable as separable
from ._translucency_technique import Translucency as Translucency
from ._translucency_technique import translucency as translucency
from ._eevee_next import EeveeNextPass as EeveeNextPass
from ._eevee_next import eevee_next as eevee_next
from ._hdrp import HdrpPass as HdrpPass
from ._hdrp import hdrp as hdrp
from ._jimenez import JimenezParams as JimenezParams
from ._jimenez import JimenezPass as JimenezPass
from ._jimenez import jimenez as jimenez
from ._separable import SCALE_LEVELS as SCALE_LEVELS
from ._separable import kernel_groups as kernel_groups
from ._separable import separable_edge_error as separable_edge_error
from ._separable import tap_chunks as tap_chunks
from ._translucency import (
    TRANSLUCENCY_MODELS as TRANSLUCENCY_MODELS,
)
from .._slab import slab_diffuse_transmittance as slab_diffuse_transmittance
from .._slab import slab_transmittance as slab_transmittance
from ._translucency import (
    sta_term as sta_term,
)
from ._translucency import (
    thin_transmittance as thin_transmittance,
)
