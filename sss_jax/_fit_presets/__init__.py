"""Artist presets: measured and artist-authored materials fitted once, saved as ``fits/<material>.json``.

Where the numbers come from (one derivation per kind of source, both documented in ``fits/README.md``):

- **measured** materials (Jensen et al. 2001, Table 2: reduced scattering ``sigma_s'`` and absorption ``sigma_a`` in
  1/mm per channel, index of refraction 1.3; ``data/measured_materials.csv``): the volume mean free path
  ``l = 1 / (sigma_s' + sigma_a)`` and single-scattering albedo ``alpha' = sigma_s' / (sigma_s' + sigma_a)``
  (similarity theory: isotropic scattering with the reduced coefficients); the surface albedo ``A`` is the total
  diffuse reflectance of a Monte Carlo random walk in that medium (pencil beam, eta = 1.3, specular reflection
  excluded), and ``d = l / s(A)`` with the memo's searchlight fit ``s(A) = 1.85 - A + 7 |A - 0.8|^3``
  (Christensen & Burley 2015, Eq. 6: the fit for normal incidence with the mean free path as the length).
- **artist** materials (surface albedo ``A`` and Burley's ``d`` per channel, as artists set them in Blender,
  HDRP or UE): the medium behind them is the one with an index-matched boundary whose pencil-beam total reflectance
  is ``A``. For isotropic scattering that is exact: ``A = 1 - H(1) sqrt(1 - alpha)`` with Chandrasekhar's H-function
  (Radiative Transfer, 1960, Ch. V; the plane albedo of a semi-infinite atmosphere), inverted for ``alpha``;
  ``l = d s(A)``. The Monte Carlo run of that medium then checks the inversion (its total reflectance must be ``A``).

Each preset then holds Burley's d, the two-Gaussian kernel fitted to the Burley profile (and one fitted to the Monte
Carlo profile), the STA parameters fitted to slab transmission, the error of each cheap model against Burley and
against Monte Carlo with the metric named, every fit's record, an engine block per engine (``engines``), and the
taps of the two-Gaussian kernel as HLSL and GLSL arrays. Monte Carlo runs are cached in ``fits/montecarlo/`` with
their provenance (photons, seed, version) and reused only when all of it matches.

The pipeline, one concept per file: ``_sources`` (materials and the medium behind them), ``_references`` (the Monte
Carlo cache and Burley's d fitted to it), ``_errors`` (every model's error), ``_pipeline`` (one preset, all presets)
and ``_files`` (plots and tables).
"""

from ._errors import (
    engine_errors as engine_errors,
    image_errors as image_errors,
    kernel_errors as kernel_errors,
    profile_errors as profile_errors,
    sta_errors as sta_errors,
    transmission_curves as transmission_curves,
)
from ._files import (
    ENGINE_ORDER as ENGINE_ORDER,
    engine_rows as engine_rows,
    load_presets as load_presets,
    plot_preset as plot_preset,
    preset_rows as preset_rows,
    write_presets_readme as write_presets_readme,
)
from ._pipeline import check_preset_name as check_preset_name, export_taps as export_taps, fit_preset as fit_preset
from ._pipeline import LEAST_PHOTONS as LEAST_PHOTONS, fit_presets as fit_presets
from ._references import (
    fit_burley_d as fit_burley_d,
    montecarlo_medium_slabs as montecarlo_medium_slabs,
    montecarlo_profiles as montecarlo_profiles,
    montecarlo_slabs as montecarlo_slabs,
)
from ._sources import (
    ARTIST_MATERIALS as ARTIST_MATERIALS,
    DEFAULT_PHOTONS as DEFAULT_PHOTONS,
    albedo_from_surface_albedo as albedo_from_surface_albedo,
    chandrasekhar_h as chandrasekhar_h,
    material_names as material_names,
    material_source as material_source,
    measured_materials as measured_materials,
)
