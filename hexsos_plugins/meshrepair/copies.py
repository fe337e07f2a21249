"""Cells written twice, repaired once.

Gmsh's MSH 2 writes an element once per physical group it belongs to: a volume in two groups comes back from
meshio with every cell twice, each copy on the same points as its original. The repair's machinery reads faces
shared by two cells as inside the mesh, so a copy would hide the boundary under it; it moves each cell once
(:func:`written_twice` finds the copies, the repair runs on the originals) and hands back a result about every cell
the caller gave (:func:`restore`): a copy's verdict, minimum and scaled Jacobian are its original's, the points
being the same. Nothing is dropped: ``hexsos repair`` writes every copy back.
"""

from __future__ import annotations

import numpy as np

from ..cells.topology import repeated_cells
from ..errors import InvalidInputError

__all__ = ["written_twice", "originals", "restore"]


def written_twice(blocks):
    """``repeated_cells(blocks)`` (validated blocks; each cell's first earlier cell of its type on the same points,
    -1: none), or None where no cell is written twice."""
    twin = repeated_cells(blocks)
    return twin if (twin >= 0).any() else None


def originals(blocks, twin):
    """The blocks without their copies (``twin`` from :func:`written_twice`; a block left empty is left out)."""
    keep = twin < 0
    out, start = [], 0
    for name, conn in blocks:
        conn = np.asarray(conn)
        mine = keep[start:start + len(conn)]
        if mine.any():
            out.append((name, conn[mine]))
        start += len(conn)
    return out


def restore(res, twin, hexes_given, other_cells=None):
    """The result ``res`` of the repair of the originals made about every cell given (``twin`` from
    :func:`written_twice`, over the hexes given, ``hexes_given`` of them, then the other cells): its certificate
    (``res.check``: the hexes, or every cell for the curved repair) and ``extra["curved_scaled_jacobian"]`` taken
    row by row from the originals'; ``other_cells``, the other cells' certificates over the cells as given (the
    caller's :func:`~hexsos_plugins.meshrepair.check_cells` on the repaired points), replaces the originals' and
    counts in ``success``; ``stats["repeated_cells"]`` counts the copies, and the message says what was done."""
    keep = twin < 0
    source = np.where(keep, np.arange(twin.size), twin)
    index = (np.cumsum(keep) - 1)[source]  # each given cell's row among the originals
    curved = res.stats.get("method") == "curved"
    rows = index if curved else index[:hexes_given]
    if rows.size and rows.max() >= len(res.check):
        raise InvalidInputError(f"cells written twice: expected a certificate of {int(keep.sum())} cells, found "
                                f"{len(res.check)}")
    old = res.check
    new = old.take(rows)
    new.seconds, new.sos_solves, new.boxes = old.seconds, old.sos_solves, old.boxes
    new.extra = dict(old.extra)
    if old.scaled_jacobian is not None:
        new.scaled_jacobian = old.scaled_jacobian[rows]
    mine = twin if curved else twin[:hexes_given]
    if (mine >= 0).any():
        new.extra["repeated_cells"] = mine
    res.check = new
    if curved and "curved_scaled_jacobian" in res.extra:
        res.extra["curved_scaled_jacobian"] = np.asarray(res.extra["curved_scaled_jacobian"])[index]
    if other_cells is not None:
        res.extra["other_cells"] = other_cells
        res.success = bool(res.success and all((o["status"] == 1).all() for o in other_cells))
    n = int((twin >= 0).sum())
    res.stats["repeated_cells"] = n
    res.stats["success"] = res.success
    said = (f"{n} cell{'s' if n != 1 else ''} written twice, on the same points as an earlier one: repaired once, "
            "each copy's certificate its original's")
    res.message = f"{res.message} ({said})" if res.message else said
    res.stats["message"] = res.message
    return res
