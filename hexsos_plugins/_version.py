"""The version, read from the installed distribution's metadata (set in pyproject.toml only)."""

from __future__ import annotations

try:
    from importlib.metadata import PackageNotFoundError, version

    __version__ = version("hexsos")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"
