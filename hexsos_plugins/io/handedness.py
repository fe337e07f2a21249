"""The handedness a file's cells are written in: which cells to flip, said once for every door.

A cell written in the mirrored node order is negative at its centre however its points are placed; a cell written
in the other handedness than its neighbours folds over them. :func:`right_handed` names them in a
:class:`~hexsos_plugins.errors.LeftHandedMeshError` or, asked to, flips exactly them
(:meth:`~hexsos_plugins.io.mesh.Mesh.flipped`). The command line (``--fix-orientation``), the Gmsh panel ("Fix
orientation") and the ParaView repair filter (``FixOrientation``) all call it, each with its own words for the
option (``hint``).
"""

from __future__ import annotations

import numpy as np

from ..cells.elements import CELL_TYPES
from ..errors import LeftHandedMeshError

__all__ = ["right_handed", "mirrored_cells"]


def right_handed(mesh, fix: bool, *, folded: bool = False, name: str | None = None,
                 hint: str = "Pass --fix-orientation to flip them"):
    """The cells of ``mesh`` (a :class:`~hexsos_plugins.io.mesh.Mesh`) written in the mirrored node order: an error
    naming them, unless ``fix``, which flips exactly those.

    Mirrored: every cell of a type negatively oriented (the file mirrors that type's node order), or the cells
    that :meth:`~hexsos_plugins.io.mesh.Mesh.mirrored_cells` finds by the faces they share and by blocks (a
    mirrored region beside a right-handed one, a block written mirrored). ``folded``: also the cells written in
    the other handedness than most of their part whatever their signs
    (:meth:`~hexsos_plugins.io.mesh.Mesh.folded_cells`: what a repair refuses; it reads every face, seconds on a
    million hexes); read so anyway when some cell is negative at its centre.

    Parameters
    ----------
    name : str, optional
        What the message calls the mesh (default: its path, else "the mesh").
    hint : str
        The message's last sentence: how to flip them with the caller's door.

    Returns
    -------
    (mesh, orientation, flipped)
        ``mesh`` itself when nothing is mirrored, else its flipped copy; ``orientation`` is ``"right-handed"``,
        ``"mixed"``, ``"left-handed (TYPES)"`` or ``"mirrored (COUNTS)"`` (the last two are flipped); ``flipped``
        the (n_cells,) bool mask of the cells flipped.

    Raises
    ------
    LeftHandedMeshError
        Some cells are mirrored and ``fix`` is False.
    """
    overall, left, some, flip, said = _mirrored(mesh, folded)
    if not flip.any():
        return mesh, overall, flip
    if not fix:
        what = name or mesh.path or "the mesh"
        raise LeftHandedMeshError(f"{what} is {'partly mirrored' if some else 'left-handed'}: {said}. {hint}")
    out = mesh.flipped(cells=flip)
    if not some:
        return out, f"left-handed ({', '.join(left)})", flip
    which = [f"all {t}" for t in left] + [f"{k} {t}" for t, k in some.items()]
    return out, f"mirrored ({', '.join(which)} cells)", flip


def mirrored_cells(mesh, *, folded: bool = False):
    """What :func:`right_handed` finds, for a door that checks cells as they are written and says what it found
    beside its verdicts: ``(mask, sentence)``, the (n_cells,) bool mask of the cells written in the mirrored node
    order (a type all negative at its centres, or cells whose faces meet their neighbours' the wrong way round:
    they fold over them, valid or not cell by cell) and the sentence that names them ("" when there are none).
    ``folded`` as for :func:`right_handed` (the faces are read anyway when some cell is negative at its
    centre)."""
    _, _, _, flip, said = _mirrored(mesh, folded)
    return flip, said


def _mirrored(mesh, folded):
    """(the orientation of the whole, the left-handed types, {type: its mirrored cells}, the mask of every cell to
    flip, the sentence naming them)"""
    det = mesh.centre_det()  # one pass for both rules
    overall, per_type = mesh.orientation_and_types(det)
    left = [t for t, o in per_type.items() if o == "left-handed"]
    # a mesh with a cell negative at its centre is read for folds too (what it names is what a repair would flip)
    mirrored = mesh.mirrored_cells(det, folded=folded or bool((det < 0).any()))
    types = mesh.cell_types
    for t in left:
        mirrored[types == CELL_TYPES.index(t)] = False
    counts = mesh.counts_by_type()
    some = {t: int(np.count_nonzero(mirrored[types == CELL_TYPES.index(t)])) for t in counts}
    some = {t: k for t, k in some.items() if k}
    said = []
    if left:
        said.append(", ".join(f"all {counts[t]} {t} cells" for t in left) + " are negatively oriented (det J < 0 at "
                    "their centres; the file uses the mirrored node order)")
    if some:
        rows = np.flatnonzero(mirrored)
        shown = ", ".join(map(str, rows[:5])) + (", ..." if len(rows) > 5 else "")
        said.append(" and ".join(f"{k} of the {counts[t]} {t} cells" for t, k in some.items())
                    + f" (cells {shown}) are written in the mirrored node order: their faces meet their neighbours' "
                    "the wrong way round (valid or not cell by cell, they fold over them), or their block is "
                    "negative throughout)")
    flip = mirrored | np.isin(types, [CELL_TYPES.index(t) for t in left])
    return overall, left, some, flip, "; ".join(said)
