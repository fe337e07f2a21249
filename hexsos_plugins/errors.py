"""The exceptions of hexsos. Library code raises these; only the CLI turns them into one line and an exit code.

Every message says what was expected and what was found.
"""

from __future__ import annotations

__all__ = [
    "HexsosError",
    "MeshReadError",
    "UnsupportedFormatError",
    "MeshFormatError",
    "NoHexahedraError",
    "NoCellsError",
    "InvalidInputError",
    "LeftHandedMeshError",
    "MeshWriteError",
    "SolverError",
    "RepairError",
    "DependencyError",
]


class HexsosError(Exception):
    """Base class of every error hexsos raises on purpose."""


class MeshReadError(HexsosError, ValueError):
    """A mesh file could not be read (missing, empty, truncated, malformed)."""


class UnsupportedFormatError(MeshReadError):
    """The file's extension or content is not a mesh format hexsos can read or write."""


class MeshFormatError(MeshReadError):
    """The file is in a known format but its content is malformed."""


class NoHexahedraError(HexsosError, ValueError):
    """The mesh holds no hexahedra: there is nothing to check."""


class NoCellsError(NoHexahedraError):
    """The mesh holds no 3-D cell of a type hexsos checks (a NoHexahedraError, for the callers that catch that)."""


class InvalidInputError(HexsosError, ValueError):
    """Arrays given to the API have the wrong shape, type or values (NaN, index out of range, ...)."""


class LeftHandedMeshError(HexsosError, ValueError):
    """Cells of the mesh are written in the mirrored node order: every cell of a type negatively oriented (a
    left-handed file), or a block or part whose faces meet their neighbours' the wrong way round."""


class MeshWriteError(HexsosError, OSError):
    """A mesh could not be written (unknown extension, format cannot hold the data, I/O error)."""


class SolverError(HexsosError, RuntimeError):
    """The convex solver could not be built or run at all (not a status: statuses are carried in results)."""


class RepairError(HexsosError, RuntimeError):
    """A repair could not be carried out as asked (for example: pinned boundary leaves no freedom)."""


class DependencyError(HexsosError, ImportError):
    """An optional dependency needed for this feature is not installed; the message names the extra."""
