"""sss_jax: differentiable real-time subsurface scattering in image space.

The public face; the implementation lives in private modules (``_profiles``, ``_kernels``, ``_scene``,
``_materials``, ``_techniques``, ...).
"""

__version__ = "0.1.0"

from ._units import mm_to_px as mm_to_px, px_per_mm as px_per_mm
from ._profiles import (
    AbstractProfile as AbstractProfile,
    BurleyProfile as BurleyProfile,
    GaussianSumProfile as GaussianSumProfile,
    TabulatedProfile as TabulatedProfile,
    burley_R as burley_R,
    burley_cdf as burley_cdf,
    burley_inverse_cdf as burley_inverse_cdf,
    burley_inverse_ccdf as burley_inverse_ccdf,
    scaling_searchlight as scaling_searchlight,
    scaling_diffuse_transmission as scaling_diffuse_transmission,
    scaling_diffuse_mfp as scaling_diffuse_mfp,
    d_from_mfp as d_from_mfp,
    preintegrate as preintegrate,
    marginal_cdf as marginal_cdf,
)
from ._kernels import (
    SeparableKernel as SeparableKernel,
    SpiralSamples as SpiralSamples,
    separable_kernel_from_profile as separable_kernel_from_profile,
    spiral_samples as spiral_samples,
    tap_offsets as tap_offsets,
    two_gaussian_kernel as two_gaussian_kernel,
)
from ._materials import (
    BurleyMaterial as BurleyMaterial,
    DirectionalLight as DirectionalLight,
    ProfileMaterial as ProfileMaterial,
    STAParams as STAParams,
    TwoGaussianMaterial as TwoGaussianMaterial,
)
from ._scene import (
    Buffers as Buffers,
    Camera as Camera,
    demo_scene as demo_scene,
    normals_from_depth as normals_from_depth,
    validate_buffers as validate_buffers,
)
from ._techniques import (
    ENERGY_CONSERVING as ENERGY_CONSERVING,
    BURLEY_PATTERNS as BURLEY_PATTERNS,
    TECHNIQUES as TECHNIQUES,
    ReferenceWindowWarning as ReferenceWindowWarning,
    SamplingWarning as SamplingWarning,
    burley as burley,
    get_technique as get_technique,
    reference as reference,
    reference_energy_held as reference_energy_held,
    reference_radius_px as reference_radius_px,
    separable as separable,
    slab_transmittance as slab_transmittance,
    thin_transmittance as thin_transmittance,
    translucency as translucency,
)
from ._engines import (
    ENGINES as ENGINES,
    blender_to_burley as blender_to_burley,
    burley_to_blender as burley_to_blender,
    burley_to_eevee as burley_to_eevee,
    burley_to_hdrp as burley_to_hdrp,
    burley_to_jimenez as burley_to_jimenez,
    burley_to_unreal as burley_to_unreal,
    convert as convert,
    eevee_to_burley as eevee_to_burley,
    engine_blocks as engine_blocks,
    engine_profile_error as engine_profile_error,
    from_engine as from_engine,
    hdrp_to_burley as hdrp_to_burley,
    jimenez_kernel as jimenez_kernel,
    jimenez_to_burley as jimenez_to_burley,
    to_engine as to_engine,
    unreal_to_burley as unreal_to_burley,
)
from ._advise import advise as advise
