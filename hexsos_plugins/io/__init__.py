"""The io wing: mesh files in and out, and the mesh object that carries a file's content.

Owns: the public entry points (:func:`read`, :func:`write`, :func:`supported_extensions`, :func:`read_meshio`),
the mesh model (:mod:`.mesh`: :class:`~hexsos_plugins.io.mesh.Mesh` keeps everything of a file, checkable cells in
VTK node order, orientation), which cells a file writes mirrored and their flip (:mod:`.handedness`: one rule and
one message for every door), the one format registry (:mod:`.formats`: names, extensions, aliases, which reader
reads what), meshio's conventions (:mod:`.meshio_conventions`: its output captured, node-order corrections), the
readers (:mod:`.readers`: one module per reader: meshio, VTK's and Gmsh's own readers, a numpy fast path for
binary MSH, tolerant readers of published variants) and the writers (:mod:`.writers`: atomic writes, each
format's own node order, what a format cannot hold said in warnings).

May import: the kernel wing (orientation), the cells wing, :mod:`hexsos_plugins.errors`. Never the repair, the
command line or the doors.
"""

from __future__ import annotations

from .formats import readers_for, supported_extensions
from .readers import read, read_meshio
from .writers import write

__all__ = ["read", "write", "supported_extensions", "read_meshio", "readers_for"]
