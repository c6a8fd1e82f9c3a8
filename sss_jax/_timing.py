"""Timing calls: the one owner of wall-clock measurement (demo, report, bench, advise). Each run is waited for
(``block_until_ready`` where the result has it), so asynchronous dispatch does not hide the work."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

__all__ = ["run_times", "side_by_side", "time_call"]


def _wait(out: Any) -> Any:
    return out.block_until_ready() if hasattr(out, "block_until_ready") else out


def run_times(fn: Callable[[], Any], repeats: int) -> list[float]:
    """Wall time in seconds of each of ``repeats`` runs of ``fn`` (no warm-up run: call ``time_call`` or run it once
    first where compilation must not count)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        _wait(fn())
        times.append(time.perf_counter() - t0)
    return times


def time_call(fn: Callable[[], Any], repeats: int, warmup: int = 0) -> tuple[np.ndarray, float, float]:
    """``(output, seconds, compile_seconds)``: the output as NumPy, the median wall time in seconds of ``repeats``
    runs after the first (the first's time when ``repeats`` is 0), and how much longer the first run took (compilation
    and first-touch costs; 0 when it was not longer). ``warmup``: runs after the first that are not timed (on
    XLA:CPU an executable's first few runs after its compilation take 2-4x its steady time, a plain 25-tap separable
    filter's too: what a benchmark of the steady state leaves out, as it does for what it compares with)."""
    t0 = time.perf_counter()
    out = _wait(fn())
    first = time.perf_counter() - t0
    run_times(fn, warmup)
    times = run_times(fn, repeats)
    seconds = float(np.median(times)) if times else first
    return np.asarray(out), seconds, max(first - seconds, 0.0)


def side_by_side(fns: Mapping[str, Callable[[], Any]], rounds: int, warmup: int = 0) -> tuple[dict[str, float],
                                                                                           dict[str, float]]:
    """``(seconds, first_extra)`` by name: the median wall time of each function over ``rounds`` rounds, each of
    which runs every function once in turn, and how much longer each one's first run took (compilation). Timed so,
    a change in the machine's speed during the run (another job, the clock) falls on all of them alike and their
    ratios keep it out: timed one after another, the ratios of a shared 2-core machine swung 1.5x between two runs of
    the same tree. ``warmup``: untimed rounds after the first runs (an XLA:CPU executable's first runs after its
    compilation are slower than its steady state)."""
    first = {name: run_times(fn, 1)[0] for name, fn in fns.items()}
    for _ in range(warmup):
        for fn in fns.values():
            _wait(fn())
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(rounds):
        for name, fn in fns.items():
            times[name] += run_times(fn, 1)
    seconds = {name: float(np.median(t)) for name, t in times.items()}
    return seconds, {name: max(first[name] - seconds[name], 0.0) for name in fns}
