"""sss_jax: differentiable real-time subsurface scattering in image space.

The public face; the implementation lives in private modules (``_profiles``, ``_kernels``, ``_scene``,
``_materials``, ``_techniques``, ...).
"""

from ._version import __version__ as __version__
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
from ._errors import (
    HalfRangeWarning as HalfRangeWarning,
    NoSSSPixelsWarning as NoSSSPixelsWarning,
    ReferenceWindowWarning as ReferenceWindowWarning,
    SamplingWarning as SamplingWarning,
    SSSInputError as SSSInputError,
    TilePlacementError as TilePlacementError,
)
from ._techniques import (
    AbstractTechnique as AbstractTechnique,
    Burley as Burley,
    Reference as Reference,
    Separable as Separable,
    Translucency as Translucency,
    technique as technique,
    ENERGY_CONSERVING as ENERGY_CONSERVING,
    BURLEY_PATTERNS as BURLEY_PATTERNS,
    TECHNIQUES as TECHNIQUES,
    burley as burley,
    EeveeNextPass as EeveeNextPass,
    eevee_next as eevee_next,
    HdrpPass as HdrpPass,
    hdrp as hdrp,
    JimenezParams as JimenezParams,
    JimenezPass as JimenezPass,
    jimenez as jimenez,
    get_technique as get_technique,
    reference as reference,
    reference_energy_held as reference_energy_held,
    reference_radius_px as reference_radius_px,
    separable as separable,
    slab_transmittance as slab_transmittance,
    thin_transmittance as thin_transmittance,
    translucency as translucency,
)
from .engines import (
    ENGINES as ENGINES,
    AbstractEngine as AbstractEngine,
    convert as convert,
    engine_blocks as engine_blocks,
    engine_profile_error as engine_profile_error,
    from_engine as from_engine,
    get_engine as get_engine,
    jimenez_kernel as jimenez_kernel,
    random_walk_medium as random_walk_medium,
    to_engine as to_engine,
)
from ._advise import advise as advise
from ._batch import BatchResult as BatchResult, FrameResult as FrameResult, process_frames as process_frames
from ._montecarlo import MCResult as MCResult, simulate as simulate, to_tabulated_profile as to_tabulated_profile
from ._slab import MediumMaterial as MediumMaterial, slab_diffuse_transmittance as slab_diffuse_transmittance
from ._fitting import (
    fit_burley_from_image as fit_burley_from_image,
    fit_sta as fit_sta,
    fit_two_gaussian_image as fit_two_gaussian_image,
    fit_two_gaussian_profile as fit_two_gaussian_profile,
    fit_two_gaussian_to_burley as fit_two_gaussian_to_burley,
)
from ._presets import (
    Preset as Preset,
    list_presets as list_presets,
    load_preset as load_preset,
    material_for as material_for,
)
from ._evaluate import evaluate_frames as evaluate_frames, read_truth as read_truth
from ._report import (
    FrameImages as FrameImages,
    ReportData as ReportData,
    TechniqueRun as TechniqueRun,
    report as report,
)
from ._match import (
    MatchFrame as MatchFrame,
    MatchResult as MatchResult,
    load_match_frame as load_match_frame,
    match_frame as match_frame,
    match_render as match_render,
    match_report_html as match_report_html,
    write_match_html as write_match_html,
)
