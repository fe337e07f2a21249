"""What the tolerant readers share: their error type, cell blocks of any type name, meshio's reader with its
output captured.

Imports :mod:`hexsos_plugins.io.meshio_conventions` and :mod:`hexsos_plugins.io.formats` only.
"""

from __future__ import annotations

import re
from pathlib import Path

import meshio
import numpy as np

from ..formats import format_name
from ..meshio_conventions import DIMS, meshio_dimensions, missing_package, quiet_meshio, shorten

__all__ = ["ParseError", "make_block", "meshio_read"]


class ParseError(Exception):
    """A tolerant reader's failure; becomes a MeshFormatError with the path and format."""



def make_block(cell_type: str, data, dim: int | None = None):
    """A meshio CellBlock of any type name (meshio's constructor rejects e.g. 'voxel')."""
    block = meshio.CellBlock("vertex", np.zeros((0, 1), dtype=np.int64))
    block.type = cell_type
    block.data = np.asarray(data)
    block.dim = dim if dim is not None else DIMS.get(cell_type, 3)
    return block



def meshio_read(path: Path, fmt: str):
    """meshio.read with its printing captured; returns (mesh, messages) or raises ParseError. The cell blocks
    are in meshio's order for ``fmt``: pass the mesh through :func:`fix_read_order`."""
    try:
        with quiet_meshio() as log, meshio_dimensions():
            mesh = meshio.read(str(path), file_format=fmt)
    except (Exception, SystemExit) as exc:
        dep = missing_package(exc, f"{path}: reading {format_name(fmt)}")
        if dep is not None:
            raise dep from None
        said = [re.sub(r"^(Warning|Error):\s*", "", m) for m in log if not m.startswith("Info")]
        text = str(exc) if not isinstance(exc, SystemExit) else ""
        reason = "; ".join(x for x in [text] + said if x) or type(exc).__name__
        raise ParseError(shorten(reason)) from None
    return mesh, log


# ------------------------------------------------------------------------------------------------- node orders
#: The wedge's mirror, which meshio's VTK readers and writers apply (its own inverse).
