"""The installed distribution's version, read from its metadata (optimistix does the same): one source, pyproject."""

import importlib.metadata

try:
    __version__ = importlib.metadata.version("sss_jax")
except importlib.metadata.PackageNotFoundError:  # a source tree on sys.path without an install
    __version__ = "0+unknown"
