"""hexsos: certified validity and repair of finite-element meshes.

Every 3-D cell (tetrahedra, pyramids, wedges, hexahedra; linear and quadratic) gets the exact minimum of
det J over its reference element, where it occurs, and a verdict that is a proof (1 valid, 0 invalid,
-1 undecided); invalid meshes can be repaired with a certificate (Marschner et al., "Hexahedral Mesh Repair via
Sum-of-Squares Relaxation", SGP 2020).

Conventions: VTK's node orders and parametric coordinates; see :mod:`hexsos_plugins.cells.elements`.

The names below are imported on first use, so ``import hexsos_plugins`` stays cheap (a command that only
reads a file does not load the solver, the repair or the plotting).
"""

from ._version import __version__
from . import errors
from .errors import *  # noqa: F401,F403 (every error type, named once: errors.__all__)

# name -> module that defines it (imported on first access)
_LAZY = {
    "check": "certify", "CheckResult": "certify", "METHOD_NAMES": "certify", "STATUS_NAMES": "certify",
    "SOS_STATUS_NAMES": "certify",
    "read": "io", "write": "io",
    "HexMesh": "io.mesh", "Mesh": "io.mesh",
    "repair": "meshrepair", "repair_hex": "meshrepair", "RepairResult": "meshrepair",
    "scaled_jacobian": "kernel",
    "RELAXATIONS": "kernel.sos",
    "CELL_TYPES": "cells",
    "safe_step": "certify.safe_step", "SafeStepResult": "certify.safe_step",
}

__all__ = [
    "__version__",
    "check",
    "CheckResult",
    "read",
    "write",
    "HexMesh",
    "Mesh",
    "repair",
    "repair_hex",
    "scaled_jacobian",
    "RepairResult",
    "METHOD_NAMES",
    "STATUS_NAMES",
    "SOS_STATUS_NAMES",
    "RELAXATIONS",
    "CELL_TYPES",
    "safe_step",
    "SafeStepResult",
] + errors.__all__


def __getattr__(name):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'hexsos_plugins' has no attribute {name!r}")
    from importlib import import_module

    value = getattr(import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
