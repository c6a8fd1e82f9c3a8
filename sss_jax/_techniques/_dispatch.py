"""Which formulation of a pass runs: one per backend, chosen by ``jax.default_backend()`` and overridable.

- ``"xla-cpu"``: what is fastest on a 2-core CPU: constant shifts over bands of rows at quantised reach levels
  (``separable``), host-side counting and compaction of the active pixels (``burley``). Needs host round trips and
  Python-level loops that a GPU pays for.
- ``"xla-gpu"``: whole-frame, one fused loop per pass, a gather per tap/sample at each pixel's own offset (Jimenez's
  shader: no reach levels), masked dense work (no host sync). Runs on any backend; what ``"auto"`` picks off CPU.
- ``"pallas"``: the same whole-frame formulation as hand-written Pallas kernels (``_pallas``): one kernel per pass,
  the tap/sample loop inside, a block of pixels with no active pixel skipping its loop. Runs in interpret mode on a
  CPU (slow: tests only); forward only, gradients come from ``"xla-gpu"``'s formulation (a custom VJP).
"""

from __future__ import annotations

import jax

IMPLS = ("auto", "xla-cpu", "xla-gpu", "pallas")


def resolve_impl(impl: str) -> str:
    """``impl`` checked against ``IMPLS``; ``"auto"`` becomes ``"xla-cpu"`` on a CPU backend, else ``"xla-gpu"``."""
    if impl not in IMPLS:
        raise ValueError(f"impl={impl!r} is not one of {IMPLS}")
    if impl == "auto":
        return "xla-cpu" if jax.default_backend() == "cpu" else "xla-gpu"
    return impl
