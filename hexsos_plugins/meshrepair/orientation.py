"""A mesh folded over itself by its node order: the cells written in the other handedness than their neighbours.

Two cells that share a face see it in opposite directions when both are written in the same handedness; when one
is written mirrored they see it in the same direction, and once both are valid (det J > 0) they lie on the same side
of that face: they overlap. No placement of the points changes that, and the kernel's certificate, cell by cell,
does not see it. So a repair refuses such a mesh and names the cells
(:meth:`hexsos_plugins.io.mesh.Mesh.folded_cells`): flip their node order first (``hexsos repair --fix-orientation``,
:meth:`~hexsos_plugins.io.mesh.Mesh.flipped` with :meth:`~hexsos_plugins.io.mesh.Mesh.mirrored_cells`), and the
repair untangles them out of the fold. It refuses, too, a cell type whose every cell (two at least) is negative at
its centre: written mirrored throughout, a repair would turn it inside out.
"""

from __future__ import annotations

import numpy as np

from ..errors import LeftHandedMeshError
from ..io.mesh import Mesh

__all__ = ["refuse_folded", "refuse_mirrored"]


def refuse_mirrored(points, blocks) -> None:
    """Raise :class:`~hexsos_plugins.errors.LeftHandedMeshError` when a cell type of ``blocks`` (a list of (type,
    conn)) with two cells at least is left-handed (:meth:`~hexsos_plugins.io.mesh.Mesh.left_handed_types`: negative
    at some centres, positive at none): those cells are written in the mirrored node order (as ``hexsos repair``
    reads a file, :func:`hexsos_plugins.io.handedness.right_handed`), and a repair would turn them inside out (a 3^3
    grid so written: 11 s of untangling, the box reflected through itself, 2 hexes left invalid). A single cell
    negative at its centre may be inverted as well as mirrored: it is repaired."""
    blocks = [(t, c) for t, c in blocks if len(c)]
    if not blocks:
        return
    mesh = Mesh.from_cells(points, blocks)
    counts = mesh.counts_by_type()
    for t in mesh.left_handed_types():
        count = counts[t]
        if count >= 2:
            raise LeftHandedMeshError(
                f"all {count} {t} cells are negative at their centres (det J < 0): they are written in the mirrored "
                "node order, and a repair would turn them inside out. Expected cells positive at their centres: "
                "flip them first (hexsos repair --fix-orientation; Mesh.flipped(cells=Mesh.mirrored_cells()) in "
                "Python, or for hexes alone hexes[:, [4, 5, 6, 7, 0, 1, 2, 3]]), then repair")


def refuse_folded(points, hexes, others) -> None:
    """Raise :class:`~hexsos_plugins.errors.LeftHandedMeshError` naming the cells of ``hexes`` (M, 8) and
    ``others`` (a list of (type, conn), numbered after the hexes) that :meth:`Mesh.folded_cells` finds."""
    blocks = ([("hexahedron", hexes)] if len(hexes) else []) + [(t, c) for t, c in others if len(c)]
    if not blocks:
        return
    folded = np.flatnonzero(Mesh.from_cells(points, blocks).folded_cells())
    if folded.size == 0:
        return
    shown = ", ".join(map(str, folded[:8])) + (", ..." if folded.size > 8 else "")
    raise LeftHandedMeshError(
        f"{folded.size} cell{'s are' if folded.size != 1 else ' is'} written in the other handedness than the cells "
        f"around {'them' if folded.size != 1 else 'it'} (cells {shown}, hexes first, then the other cells in their "
        "order): each shared face is read the same way round from both sides, so once valid they lie on the same "
        "side of it and overlap; no placement of the points is a mesh. Expected one handedness across shared "
        "faces: flip their node order first (hexsos repair --fix-orientation; Mesh.flipped(cells="
        "Mesh.mirrored_cells()) in Python), then repair")
