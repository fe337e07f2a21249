"""The repair wing: hand back a mesh a solver can use, certified by the kernel.

Owns: the default method's driver (:mod:`.driver`: untangle, raise the quality, certify, fall back to the
paper's method), its energies and their compiled loops (:mod:`.optimize`, :mod:`.kernels`), the vertex-by-vertex
steps (:mod:`.localopt`), the boundary model
(:mod:`.boundary`: surface, features, sliding), the paper's Algorithms 1 and 2 (:mod:`.paper`), the one result
type (:mod:`.result`), the repair of meshes far from unit size at a power-of-two scale (:mod:`.scale`), the options and the one rule for their defaults (:mod:`.options`), the boundary's distance
to the input (:mod:`.fidelity`), the BLAS thread cap (:mod:`.blas`), and the repair of curved and hex-free
meshes on det J's Bernstein coefficients (:mod:`.curved`, its compiled loops :mod:`.curvedkernels`, what it and the
skeleton stand on :mod:`.curvedcells`: coefficients, curved boundary, the problem; the untangling of their folded
straight-sided skeleton first :mod:`.skeleton`), the refusal of a mesh folded over
itself by its node order (:mod:`.orientation`), and the repair of cells written twice once (:mod:`.copies`).

May import: the certify, kernel and cells wings, :class:`hexsos_plugins.io.mesh` helpers (mesh topology) and
:mod:`hexsos_plugins.errors`. Never the command line or the doors: they call :func:`repair`.
"""

from .driver import check_cells, repair, repair_hex, repair_paper
from .options import (BOUNDARY_MODES, DEFAULT_MARGIN, DEFAULT_RHO, METHODS, SURFACE_TOLERANCE, default_boundary,
                      door_boundary, resolve_boundary)
from .result import RepairResult, step_words

__all__ = ["repair", "repair_hex", "repair_paper", "RepairResult", "check_cells", "METHODS", "BOUNDARY_MODES",
           "DEFAULT_MARGIN", "DEFAULT_RHO", "SURFACE_TOLERANCE", "default_boundary", "resolve_boundary", "door_boundary",
           "step_words"]
