"""Builds the compiled kernel extension (everything else is in pyproject.toml)."""

import os
import sys

from setuptools import setup

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def _extensions():
    try:
        from hexsos_plugins.generate.extension import extension

        return [extension()]
    except Exception as exc:  # no compiler, no numba: the kernel is compiled at first use instead
        sys.stderr.write(f"hexsos: not building the compiled kernel extension ({exc}); numba compiles it at first use\n")
        return []


setup(ext_modules=_extensions())
