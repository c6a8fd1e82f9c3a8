"""Timing one jitted call: a first (compiling) run, then the median of repeated runs, each waited for."""

from __future__ import annotations

import time
from typing import Callable

import jax
import numpy as np

__all__ = ["time_call"]


def time_call(fn: Callable[[], jax.Array], repeats: int) -> tuple[np.ndarray, float, float]:
    """``(output, seconds, compile_seconds)``: the output as NumPy, the median wall time in seconds of ``repeats``
    runs after the first (the first's time when ``repeats`` is 0), and how much longer the first run took (compilation
    and first-touch costs; 0 when it was not longer)."""
    t0 = time.perf_counter()
    out = fn().block_until_ready()
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn().block_until_ready()
        times.append(time.perf_counter() - t0)
    seconds = float(np.median(times)) if times else first
    return np.asarray(out), seconds, max(first - seconds, 0.0)
