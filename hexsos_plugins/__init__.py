"""hexsos: certified validity and repair of hexahedral meshes.

Every trilinear hex gets the exact minimum of det J over its parameter cube [0, 1]^3, where it occurs,
and a verdict that is a proof (1 valid, 0 invalid, -1 undecided); invalid meshes can be repaired with a
certificate (Marschner et al., "Hexahedral Mesh Repair via Sum-of-Squares Relaxation", SGP 2020).

Conventions: nodes in VTK order; see :mod:`hexsos_plugins.hexahedron` for the diagram.
"""

from ._version import __version__
from .certify import METHOD_NAMES, SOS_STATUS_NAMES, STATUS_NAMES, CheckResult, check
from .errors import (
    DependencyError,
    HexsosError,
    InvalidInputError,
    LeftHandedMeshError,
    MeshFormatError,
    MeshReadError,
    MeshWriteError,
    NoHexahedraError,
    RepairError,
    SolverError,
    UnsupportedFormatError,
)
from .io import read, write
from .mesh import HexMesh
from .meshrepair import RepairResult, repair, repair_hex, repair_paper
from .quality import scaled_jacobian
from .sos import RELAXATIONS

__all__ = [
    "__version__",
    "check",
    "CheckResult",
    "read",
    "write",
    "HexMesh",
    "repair",
    "repair_hex",
    "repair_paper",
    "scaled_jacobian",
    "RepairResult",
    "METHOD_NAMES",
    "STATUS_NAMES",
    "SOS_STATUS_NAMES",
    "RELAXATIONS",
    "HexsosError",
    "MeshReadError",
    "UnsupportedFormatError",
    "MeshFormatError",
    "NoHexahedraError",
    "InvalidInputError",
    "LeftHandedMeshError",
    "MeshWriteError",
    "SolverError",
    "RepairError",
    "DependencyError",
]
