"""The Burley technique's spec shared by its formulations (``_burley``'s banded/compacted one, ``_burley_gpu``'s
whole-frame one): the per-sample weight kernel and the footprint radius. Imports no formulation, so each formulation
imports it without an import cycle."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._profiles import burley_inverse_ccdf


def _burley_weight_kernel(x: Array) -> Array:
    """``(exp(-x) + exp(-x/3)) / x``: the Burley profile at ``r = x d`` up to the factor ``8 pi d^2`` that cancels in
    the per-channel normalisation. ``x = inf`` (d = 0 or no overlap) gives 0; x is never 0 here (r > 0)."""
    finite = jnp.isfinite(x) & (x > 0)
    xs = jnp.where(finite, x, 1.0)
    e3 = jnp.exp(-xs / 3)  # exp(-x) = e3^3: one exponential, not two
    return jnp.where(finite, e3 * (e3 * e3 + 1) / xs, 0.0)


# radius holding 99% of a Burley profile's energy, in units of d (the footprint the skip and compaction test)
_BURLEY_R99 = float(np.asarray(burley_inverse_ccdf(np.float64(0.01), np.float64(1.0))))
