"""The cells wing: what a cell *is*, in exact arithmetic, independent of any mesh or file.

Owns: the registry of cell types (:mod:`.elements`: node orders, parametric coordinates, exact shape functions,
faces), the conventions of the trilinear hexahedron and its det J in closed form (:mod:`.hexahedron`), det J of
every type in Bernstein form (:mod:`.jacobian`: the factors, the exact rational tables the kernel is built from)
and the scaled Jacobian's definitions (:mod:`.quality`: Verdict's corner samples, a numpy reference).

May import: numpy, :mod:`hexsos_plugins.errors`. Everything else of hexsos sits above it.
"""

from .elements import CELL_TYPES, ELEMENTS, VOXEL_TO_VTK, element

__all__ = ["CELL_TYPES", "ELEMENTS", "VOXEL_TO_VTK", "element"]
