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

__all__ = ["ParseError", "make_block", "meshio_read", "node_indexer"]


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


def node_indexer(sorted_tags: np.ndarray, where: str):
    """``index(node_tags, what)``: the rows of the (ascending, unique) ``sorted_tags`` holding the given node tags,
    in their shape; a tag not among them is a ``ParseError`` naming ``what`` refers to it and that ``where`` does not
    define it. Tags 1..n (the usual numbering) are shifted in place of a copy, without a search."""
    n = len(sorted_tags)
    contiguous = n > 0 and sorted_tags[0] == 1 and sorted_tags[-1] == n

    def index(node_tags, what):
        given = node_tags
        node_tags = np.asarray(node_tags, dtype=np.int64)
        if contiguous:
            idx = node_tags.copy() if node_tags is given else node_tags
            idx -= 1  # in place: no second array of the size of the connectivity
            if len(idx) == 0 or (int(idx.min()) >= 0 and int(idx.max()) < n):
                return idx
            ok = (idx >= 0) & (idx < n)
            raise ParseError(f"{what} references node tag {int(idx[~ok].flat[0]) + 1}, which {where} does not define")
        idx = np.searchsorted(sorted_tags, node_tags)
        idx[idx >= n] = 0
        ok = sorted_tags[idx] == node_tags if n else np.zeros(idx.shape, dtype=bool)
        if not ok.all():
            raise ParseError(f"{what} references node tag {int(node_tags[~ok].flat[0])}, which {where} does not define")
        return idx

    return index
