"""Reading and writing mesh files: the public entry points (:func:`read`, :func:`write`,
:func:`supported_extensions`, :func:`read_meshio`).

The readers live in :mod:`hexsos_plugins.readers` (one module per reader: meshio, VTK's and Gmsh's own readers,
a numpy fast path for binary MSH, tolerant readers of published variants), the writers in
:mod:`hexsos_plugins.writers` (atomic writes, each format's own node order, what a format cannot hold said in
warnings). See those modules for which reader reads what and why.
"""

from __future__ import annotations

from .readers import read, read_meshio, readers_for, supported_extensions
from .readers.gmsh22_data import _read_gmsh22_data  # noqa: F401 (the tolerant readers, by their former names)
from .readers.legacy_vtk import _read_legacy_vtk  # noqa: F401
from .readers.medit import _read_medit_text  # noqa: F401
from .writers import write

__all__ = ["read", "write", "supported_extensions", "read_meshio", "readers_for"]
