"""The presets (``<material>.json``), their Monte Carlo caches and plots: installed with the package as ``sss_jax.fits``
(package data, read through ``importlib.resources``), so presets by name work from any install."""
