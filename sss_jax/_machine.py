"""A description of the machine a measurement ran on, for reports (JSON-able)."""

from __future__ import annotations

import os
import platform
import time

__all__ = ["machine_info", "usable_cores"]


def usable_cores() -> int:
    """The cores this process may run on: its CPU affinity where the OS tells it (``taskset``, a container's CPU set),
    else every core (``os.cpu_count``). What XLA sizes its CPU thread pool by; ``os.cpu_count`` counts the whole
    machine's, so work split by it would oversubscribe a restricted process."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not on Linux
        return os.cpu_count() or 1


def machine_info() -> dict:
    """Host, CPU, accelerator and library versions; the date in UTC."""
    import jax

    from importlib import metadata

    def version(pkg: str) -> str | None:
        try:
            return metadata.version(pkg)
        except metadata.PackageNotFoundError:
            return None

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), cpu)
    except OSError:
        pass
    devices = jax.devices()
    try:  # other work on the machine while timing: times taken under load read slower and noisier
        load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    except OSError:
        load = None
    return {
        "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
        "host": platform.node(),
        "os": platform.platform(),
        "cpu": cpu,
        "cpu_count": os.cpu_count(),
        "usable_cores": usable_cores(),
        "load_average_1_5_15_min": load,
        "jax_backend": jax.default_backend(),
        "devices": f"{len(devices)} x {devices[0].device_kind}" if devices else "none",
        "python": platform.python_version(),
        "jax": version("jax"),
        "sss_jax": version("sss_jax"),
    }
