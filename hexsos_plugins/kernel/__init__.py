"""The compiled kernel: det J's Bernstein coefficients with rigorous bounds, certified brackets, polish.

One compiled path for every cell type, driven by the tables of :mod:`hexsos_plugins.cells.jacobian` (numba,
``cache=True``). Per cell:

1. **coefficients**: the nodes are scaled by a power of two 2^-k (the cell's extent lands in [1, 2):
   nothing overflows, whatever the units) and taken relative to node 0; the geometry's control points
   (sparse tables of dyadic weights; a control point that is a node is copied, with no rounding term), the
   Jacobian's columns (scaled differences of control points) and det J = x_r . (x_s x x_t) by Bernstein
   products give the coefficients ``b`` and a rigorous bound ``err`` on ``|b - b_exact|`` for the cell *as
   given*, with relative rounding (u = 2^-53) and absolute underflow (eta = 2^-1074) terms (derivation:
   :mod:`hexsos_plugins.cells.jacobian`). The size of det J's terms is the permanent ``perm(A)`` of the largest
   |column coefficient| per component and direction: it scales like det J under any scaling of the axes.
   For the types with small tables (:data:`GENERATED`) the cross and dot products (and, for the linear types,
   whose control points are their nodes, the columns) run as straight-line code generated from the tables
   (:mod:`.generated`, written by :func:`hexsos_plugins.generate.codegen.write_generated`: the same operations in the same order, so the same results
   bit for bit; used only while its recorded fingerprint matches the tables');
2. **bracket**: best-first branch-and-bound over boxes (lines halved, triangles cut into 4 by their edge
   midpoints: fixed matrices with dyadic entries; a tetrahedron, when det J is one tet factor, bisected at the
   midpoint of its longest edge: de Casteljau along the lines of that edge), pruning boxes whose smallest
   coefficient minus its error bound is above the best value found minus the tolerance; the smallest bound
   of all boxes is a proven lower bound, the vertex coefficients are values (the upper bound);
3. **polish**: projected Newton from the best vertex (monomial form; the reference element's faces as
   active constraints), kept only where it lowers the value;
4. **witness**: the value at the final point from the root coefficients, with explicit non-negative basis
   weights, and its rounding bound.

No fastmath anywhere: every bound assumes IEEE-754 round-to-nearest per operation (a fused multiply-add only
removes a rounding; reassociation would break the bounds). The chunk functions release the GIL, so cells run
in parallel on Python threads (:func:`set_threads`); each chunk owns its scratch arrays, nothing is pickled, and
a small call runs in the calling thread at once.

Owns: :mod:`.compiled` (which implementation runs), :mod:`.cell_tables` (each type's tables), :mod:`.pool` (the threads),
:mod:`.calls` (the entry points), :mod:`.source` (the numba source), :mod:`.generated` (straight-line code
generated from the tables at build time by :mod:`hexsos_plugins.generate.codegen`), :mod:`.exact` (exact rational
decisions), :mod:`.sos` (the SOS relaxations on Clarabel).

May import: the cells wing and :mod:`hexsos_plugins.errors` only.
"""

from __future__ import annotations

from .calls import coefficients, det_at, det_bernstein, evaluate, finish, polish, run_cells, scaled_jacobian
from .compiled import compiles_at_first_use, implementation
from .cell_tables import Tables, tables
from .pool import cores, last_threads, set_threads, threads, threads_for

__all__ = ["run_cells", "coefficients", "det_bernstein", "evaluate", "polish", "scaled_jacobian", "det_at", "finish", "tables",
           "Tables", "set_threads", "threads", "threads_for", "last_threads", "cores", "implementation", "compiles_at_first_use", "U", "ETA"]

U = 2.0**-53  # unit roundoff
ETA = 2.0**-1074  # smallest subnormal: bounds the error of any rounding in the subnormal range
