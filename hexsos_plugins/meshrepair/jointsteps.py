"""The repair's last steps: raise the minimum scaled Jacobian by moving the vertices of the worst hexes together.

The vertex steps (:mod:`hexsos_plugins.meshrepair.localopt`) stop where the worst hexes share vertices: each vertex
alone cannot move without lowering a neighbour (cat_2 after them: eight hexes at 0.66-0.68 around a feature corner).
Here every vertex of the hexes within :data:`SPAN` of the minimum moves at once, by sequential linear programming
for the max-min. The vertices split into groups that no hex joins (:func:`vertex_groups`: a plateau's clusters; on
several threads the largest cut in two, :func:`split_layer`), and each round solves one linear program per group
(HiGHS, through :func:`scipy.optimize.linprog`, the groups' programs side by side on the kernel's threads): the
move that maximizes ``t`` with every scaled Jacobian sample of every hex around the group's vertices, linearized, at
least ``t`` plus :data:`KEEP` of its height above the group's least sample; within a trust region (a fraction of
each vertex's mean edge length); in each vertex's freedom (inside any direction; boundary vertices within their
band, as the vertex steps' last pass, the others where they are); with each hex's shortest / longest edge,
linearized, above the lesser of its own and :data:`~hexsos_plugins.meshrepair.localopt.RATIO_FLOOR`, and its low
Bernstein coefficients of det J (those of their split where the 27 come near 0: :func:`held_coefficients`),
linearized, above half their value (the vertices of a hex with a coefficient near 0 take shorter steps:
:data:`NEAR_ZERO_STEP`). A group's step is kept only where its
least sample rises, every hex passes the test of validity (its coefficients positive, or those of their split:
:mod:`hexsos_plugins.meshrepair.optimize`), no hex's edge ratio falls below its floor (less :data:`RATIO_SLACK`) and
every banded vertex stays in its band (exactly, not linearized); otherwise half and a quarter of the step are tried,
and the trust region (set by the group with the lowest hex) halves (but after half of it kept: :data:`HALF_KEEPS`).
So the steps end where they started or higher, valid, with no edge collapsed; the certificate is still the kernel's.
"""

from __future__ import annotations

import bisect
import time
import warnings

import numpy as np

from ..cells.hexahedron import EDGES
from ..cells.quality import SAMPLES, hex_edge_ratio
from .localopt import BAND_BELOW, RATIO_FLOOR, band_limits, vertex_freedoms
from .optimize import SPLIT_BELOW, bernstein_matrix, bernstein_split_matrix, cof3, hex_bernstein_samples

__all__ = ["joint_steps", "vertex_groups", "split_layer", "sample_gradients", "bernstein_gradients",
           "held_coefficients", "binding_rows", "next_delta", "SPAN", "SPLIT_VERTICES", "MAX_HEXES", "PLATEAU",
           "PLATEAU_HEXES", "RATIO_SLACK", "HALF_KEEPS", "KEEP"]

#: The hexes whose vertices move: within this of the minimum, the :data:`MAX_HEXES` lowest at most (measured on
#: the published meshes after the vertex steps, 10 s each, with a box for the band: 50 reached as high as 100 and
#: 300 (within 0.01, higher on four of eight) in 1-4 s where they took 2-10 s)
SPAN = 0.05
MAX_HEXES = 50
#: ... but where more hexes than that sit within :data:`PLATEAU` of the minimum, that many (at most
#: :data:`PLATEAU_HEXES`), from then on: a program lifts the hexes it holds while their neighbours on the same
#: plateau hold it down. kitten_with_bifur_3's worst hexes end in interior clusters of up to 411 hexes within 0.01 of
#: the minimum, the input's own low hexes (616 below 0.366); from the same start of these steps, 10 s each (one run,
#: 2026-12-04): kitten_with_bifur_3 0.366 -> 0.415 (with 100, 200, 400 always: 0.387, 0.398, 0.407), the bunny 0.828
#: -> 0.840, cat_2 0.782 -> 0.784, Dolphin_2 0.793 -> 0.796 (7.4 s -> 10 s), hex_torus 0.8652 -> 0.8654 (0.6 -> 3.9 s),
#: rockarm, dinopet_graded and warrior_graded within 0.0003 (0.850, 0.750, 0.750)
PLATEAU = 0.005
PLATEAU_HEXES = 400
#: The trust region: each vertex moves by at most this fraction of its mean edge length per coordinate of its
#: freedom; it grows by half after a whole step kept (up to ``DELTA_MAX``), stays after half of one and halves
#: otherwise (:func:`next_delta`), and the steps end below ``DELTA_MIN``.
DELTA = 0.02
DELTA_MAX = 0.1
DELTA_MIN = 1e-4
#: Bernstein coefficients below this fraction of their hex's largest enter the program (linearized, kept above half
#: their value): the others are far from 0 for a step inside the trust region.
BERNSTEIN_LOW = 0.3
#: A step is kept with every hex's shortest / longest edge at least (1 - this) times the lesser of its own at the
#: start and :data:`~hexsos_plugins.meshrepair.localopt.RATIO_FLOOR`: the program holds the floor at first order
#: only, and a hex at its floor would block every step that moves it (Dolphin_2: 31 hexes of the input below 0.05)
RATIO_SLACK = 0.005
#: The step's bound near a Bernstein coefficient close to 0 (below)
NEAR_ZERO_STEP = 0.3
#: The solver: HiGHS's interior point method (its dual simplex, on a 4^3 grid near 0.996, hit the time limit on 4
#: of 20 programs, the interior point method on 1; on the published meshes both solve each in under 0.07 s and end
#: within 0.005 of each other, but on kitten_with_bifur_3: 0.331 with the simplex, 0.296 with this, one run each).
#: With the rows that cannot bind left out (:func:`binding_rows`) the simplex is the faster (1.3 s against 2.1 s on
#: 370 programs of Dolphin_2 and the bunny), but neither ends higher: from the input and from a start perturbed by
#: 1e-12, kitten_with_bifur_3 0.334 / 0.341 with the simplex against 0.299 / 0.356, rockarm 0.845 / 0.829 against
#: 0.848 / 0.850, Dolphin_2 0.786 / 0.743 against 0.787 / 0.765. A program taking longer than ``LP_SECONDS`` is
#: given up (the trust region halves).
LP_METHOD = "highs-ipm"
#: HiGHS's options beyond the time limit: the interior point method's solution as it ends, without the crossover to
#: a vertex of the optimal face, at a gap of 1e-6 instead of 1e-8. Offline on 8 of kitten_with_bifur_3's programs
#: the optimum is the same to 1e-9 in 15-25% less time, and the solution lies inside the optimal face, its move
#: spread over every vertex that can give it (a vertex solution moves some and leaves others where they are). Over
#: three starts of kitten_with_bifur_3 (``python -m comparison.bench_repair --published --starts 3``, 2026-12-06):
#: 0.500 / 0.500 / 0.496 with the crossover, 0.508 / 0.507 / 0.508 without it, 0.515 / 0.514 / 0.510 at 1e-6
#: too; at 1e-5 0.515 / 0.494 / 0.511, and at 1e-4 HiGHS ends most programs without a solution (0.258). The
#: other seven published meshes' medians the same or higher (cat_2 0.846 -> 0.851, its first start 0.791 -> 0.841).
#: A scipy that leaves out the options it does not know (Debian's 1.10, in ParaView's Python) keeps the crossover.
LP_OPTIONS = {"run_crossover": "off", "ipm_optimality_tolerance": 1e-6}
#: A step refused whole is tried at these parts of it before the next program: the program's move raises the
#: linearized minimum all along it, and a part often keeps a gain the whole loses at second order (38% of rockarm's
#: steps were refused whole). A try costs an evaluation, a program about ten times more. On the published meshes the
#: joint steps end as high or higher in less time: rockarm 0.838 in 10 s (their budget) -> 0.842 in 7.7 s,
#: Dolphin_2 0.775 in 10 s -> 0.776 in 7.1 s, kitten_with_bifur_3 0.350 -> 0.360 in their 10 s.
STEP_PARTS = (1.0, 0.5, 0.25)
LP_SECONDS = 0.5
#: On more than one of the kernel's threads, a group of more vertices than this is split in two each round
#: (:func:`split_layer`): its program held one thread for most of the round while the other solved the small groups'
#: (kitten_with_bifur_3's plateau, one group of 700-940 vertices, programs of 2,000-3,000 columns taking 0.2-0.5 s,
#: the other eight to twenty groups' together a tenth of that). The vertices of the hexes across the cut stay for
#: that round, on one side or the other and across x, y, z in turn. kitten_with_bifur_3, as ``hexsos repair`` (every
#: core; one run each, 2026-12-06): 0.515 / 0.514 / 0.512 / 0.515 without, 0.529 / 0.528 / 0.529 with 500 (400: 0.530 /
#: 0.525; 300: 0.524; 200: 0.521; split again up to four times at 300: 0.515, eight at 150: 0.403, the steps ending
#: on their patience while the lowest hex's vertices stayed). On one thread the split gained nothing (0.512 -> 0.508).
SPLIT_VERTICES = 500
#: After a step kept at half its move the trust region stays as it was (it halved before): the next program's
#: move, of the same size, is again tried whole, then at half. From kitten_with_bifur_3's repaired mesh (0.444),
#: 20 s of these steps reached 0.461 in 89 programs (33 kept at a part) with the region halved, 0.475 in 62 (49)
#: with it kept, and 0.476 in 51 (44) kept after a quarter step too (one run each, the same start)
HALF_KEEPS = True
#: Each sample of a program keeps this fraction of its height above the minimum (linearized: ``sj + g.d >= m + t +
#: KEEP (sj - m)``, t the program's gain): without it a program is free to take any sample down to the new
#: minimum, its solution (a vertex of the optimal face) does, and the worst hexes' neighbours pile up there.
#: kitten_with_bifur_3's 1,564 hexes within 0.01 of its minimum after the repair included hexes at 0.74-0.97 in
#: its input. Medians over three starts (``python -m comparison.bench_repair --published --starts 3``, 2026-12-05),
#: 0 -> 0.2: kitten_with_bifur_3 0.480 -> 0.487 (0.455 / 0.480 / 0.489 -> 0.470 / 0.489 / 0.487), the bunny 0.837
#: -> 0.848, Dolphin_2 0.781 -> 0.787, rockarm 0.846 -> 0.847, the others the same; kitten's medians with 0.1 and
#: 0.3, 0.482 and 0.483; single runs of kitten: 0.5 0.476, 0.8 0.439 (the steps hold back too much)
KEEP = 0.2
#: The steps end when ``PATIENCE`` tries in a row raise the minimum by less than ``MIN_GAIN`` in all.
PATIENCE = 8
MIN_GAIN = 1e-4

# scipy hands the options it does not know to HiGHS as they are, and warns that it does on every call; an older
# scipy (Debian's 1.10, ParaView's Python) leaves them out, HiGHS then ending with its crossover, and warns so
warnings.filterwarnings("ignore", message=r"Unrecognized options detected: \{'run_crossover': 'off'\}\. These will be "
                        r"passed to HiGHS verbatim\.")
warnings.filterwarnings("ignore", message=r"Unknown solver options: run_crossover$")

_GB = hex_bernstein_samples()
_TB = bernstein_matrix()
_SPLIT = bernstein_split_matrix()
_E = np.asarray(EDGES)


def _cofactors(E):
    """d det / dE of matrices E (..., 3, 3): :func:`hexsos_plugins.meshrepair.optimize.cof3` on the last two axes."""
    return np.moveaxis(cof3(np.moveaxis(E, (-2, -1), (0, 1))), (0, 1), (-2, -1))


def sample_gradients(X):
    """The scaled Jacobian samples of hexes X (M, 8, 3) (:data:`hexsos_plugins.cells.quality.SAMPLES`) and their
    gradients with respect to X: (M, K), (M, K, 8, 3)."""
    G, factor = SAMPLES["hexahedron"]
    E = np.tensordot(X, G, axes=([1], [1])).transpose(0, 2, 1, 3)  # (M, K, 3, 3); einsum's loop took 30x longer
    det = np.linalg.det(E)
    L2 = (E * E).sum(axis=2)
    prod = np.sqrt(L2).prod(axis=2)
    sj = factor * det / prod
    dE = factor * (_cofactors(E) / prod[..., None, None] - (det / prod)[..., None, None] * E / L2[..., None, :])
    return sj, np.matmul(G[None], dE.transpose(0, 1, 3, 2))  # (M, K, 8, 3)


def bernstein_gradients(X, low=None):
    """The 27 Bernstein coefficients of det J of hexes X (M, 8, 3), (M, 27), and their gradients.

    Without ``low``: every coefficient's gradient, (M, 27, 8, 3). With ``low`` (a fraction): only those of the
    coefficients below ``low`` times their hex's largest, as (hexes (P,), coefficients (P,), gradients (P, 8, 3))
    -- the joint steps need a few (rockarm: all 27 for each hex took a quarter of their time)."""
    J = np.tensordot(X, _GB, axes=([1], [1])).transpose(0, 2, 1, 3)  # (M, 27, 3, 3)
    b = np.linalg.det(J) @ _TB.T

    def sample_det_gradients(Js):  # (U, 27, 8, 3): det J's gradient at each of the 27 samples
        return np.matmul(_GB[None], _cofactors(Js).transpose(0, 1, 3, 2))

    if low is None:
        return b, np.einsum("ps,msna->mpna", _TB, sample_det_gradients(J))
    hh, pp = np.nonzero(b < low * b.max(axis=1)[:, None])
    u, inv = np.unique(hh, return_inverse=True)
    return b, (hh, pp, np.einsum("ps,psna->pna", _TB[pp], sample_det_gradients(J[u])[inv.ravel()]))


def held_coefficients(X, low, split_below=SPLIT_BELOW):
    """The coefficients of det J the joint steps hold, of hexes X (M, 8, 3): each hex's 27, or where the least of
    them is below ``split_below`` of the largest, the 216 of their split (one subdivision,
    :func:`hexsos_plugins.meshrepair.optimize.bernstein_split_matrix`: the 27's least is often their slack, not
    det J's; kitten_with_bifur_3's steps stopped at hexes whose least was 6e-10 of their largest and det J's least
    0.1 of it). Returns (least (M,), largest (M,), (hh (P,), values (P,), gradients (P, 8, 3))): every hex's least
    and largest held coefficient, and those below ``low`` times their hex's largest with their gradients."""
    b, (hh, pp, db) = bernstein_gradients(X, low=low)
    least, largest = b.min(axis=1), b.max(axis=1)
    split = least < split_below * largest
    if not split.any():
        return least, largest, (hh, b[hh, pp], db)
    keep = ~split[hh]
    hh, vals, db = hh[keep], b[hh[keep], pp[keep]], db[keep]
    su = np.flatnonzero(split)
    c = b[su] @ _SPLIT.T  # (S, 216)
    least[su], largest[su] = c.min(axis=1), c.max(axis=1)
    ss, qq = np.nonzero(c < low * largest[su][:, None])
    if ss.size:
        J = np.tensordot(X[su], _GB, axes=([1], [1])).transpose(0, 2, 1, 3)  # (S, 27, 3, 3)
        dJ = np.matmul(_GB[None], _cofactors(J).transpose(0, 1, 3, 2))  # (S, 27, 8, 3): det J's at the samples
        dc = np.einsum("qs,qsna->qna", (_SPLIT @ _TB)[qq], dJ[ss])
        hh = np.concatenate([hh, su[ss]])
        vals = np.concatenate([vals, c[ss, qq]])
        db = np.concatenate([db, dc])
    return least, largest, (hh, vals, db)


def _rows(coef, vid, col, B, row):
    """COO entries of rows ``row`` (P,) with coefficient vectors ``coef`` (P, 3) on vertices ``vid`` (P,), in the
    variables y (3 per vertex, in the vertex's basis B): the entries of vertices without a column are dropped."""
    c = col[vid]
    keep = c >= 0
    gy = np.einsum("pa,pad->pd", coef[keep], B[vid[keep]])
    return (np.repeat(row[keep], 3), (3 * c[keep][:, None] + np.arange(3)).ravel(), gy.ravel())


def next_delta(delta, kept_part):
    """The trust region after a program whose move was kept at ``kept_part`` of it (0: refused): it grows by half
    after the whole move (up to ``DELTA_MAX``), stays after half of it (:data:`HALF_KEEPS`), and halves otherwise."""
    if kept_part == 1.0:
        return min(1.5 * delta, DELTA_MAX)
    if HALF_KEEPS and kept_part == 0.5:
        return delta
    return 0.5 * delta


def binding_rows(A, b, box, n_t):
    """The rows of the program ``A [d, t] <= b`` (d within +-``box``, the first ``n_t`` rows the samples', with t)
    that can bind. Every sample row bounds t by its right side plus its largest move term, so t <= T, the least of
    these; a sample row whose right side is above T plus its own largest move term, or another row whose right
    side is above its largest move term, holds for every point of the box: it is left out (the program's feasible
    set stays the same; on the published meshes 85-95% of the rows, and a quarter to a half of the solver's time
    on Dolphin_2, cat_2 and the bunny)."""
    reach = abs(A[:, :-1]) @ box
    T = float(np.min(b[:n_t] + reach[:n_t]))
    need = reach + np.where(np.arange(b.size) < n_t, T, 0.0)
    keep = ~(b > need)
    return A[keep], b[keep]


def split_layer(V, H, verts, vmask, turn):
    """The vertices that stay in this round so that ``verts`` (one group of :func:`vertex_groups`) fall in two: cut
    at the median of one coordinate (x, y, z in turn), the vertices of the hexes that hold moved vertices of both
    sides stay on one side (the lower and the upper in turn). ``H``: the mesh's hexes or the group's alone (no hex
    joins two groups: the same cut). Returns (N,) bool."""
    axis, side = turn % 3, (turn // 3) % 2
    c = V[verts, axis]
    lower = np.zeros(vmask.size, dtype=bool)
    lower[verts[c < np.median(c)]] = True
    on = vmask[H]
    lo = (on & lower[H]).any(axis=1)
    hi = (on & ~lower[H]).any(axis=1)
    cross = H[lo & hi]
    stay = np.zeros(vmask.size, dtype=bool)
    stay[cross.ravel()] = True
    return stay & vmask & (lower if side == 0 else ~lower)


def vertex_groups(vmask, H):
    """The vertices of ``vmask`` (N,) bool split into groups no hex of ``H`` joins: two vertices of one hex are in one
    group. Returns [(vertices, hexes)] (each group's vertices and the hexes holding any of them), the most vertices
    first: the hexes of two groups are disjoint, so their programs are independent and their steps add up."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    N = vmask.size
    hx = np.flatnonzero(vmask[H].any(axis=1))
    Hx = H[hx]
    on = vmask[Hx]
    first = Hx[np.arange(hx.size), on.argmax(axis=1)]  # each hex's first moved vertex, joined to its others
    A = coo_matrix((np.ones(int(on.sum())), (np.repeat(first, on.sum(axis=1)), Hx[on])), shape=(N, N))
    _, label = connected_components(A, directed=False)
    verts = np.flatnonzero(vmask)
    order = np.argsort(label[verts], kind="stable")
    keys, starts = np.unique(label[verts][order], return_index=True)
    hex_label = label[first]
    hex_order = np.argsort(hex_label, kind="stable")
    bounds = np.searchsorted(hex_label[hex_order], keys)
    groups = [(verts[order][a:b], hx[hex_order][c:d]) for a, b, c, d in
              zip(starts, np.r_[starts[1:], verts.size], bounds, np.r_[bounds[1:], hx.size])]
    return sorted(groups, key=lambda g: -g[0].size)


def joint_steps(V, H, movable, *, boundary=None, deadline=None, target=None, band_below=BAND_BELOW, span=SPAN,
                max_hexes=None, max_tries=500, go_on=None):
    """Raise the minimum scaled Jacobian of hexes H at V by joint moves of the vertices of the worst hexes (module
    docstring). ``movable`` (N,) bool; ``boundary``: a :class:`hexsos_plugins.meshrepair.boundary.BoundaryModel`
    with a band (its vertices of hexes below ``band_below`` or within twice ``span`` of the minimum at the start
    move within it, the other boundary vertices stay) or None (no constraint but ``movable``); ``target``: stop
    once the minimum reaches it; ``max_hexes``: the hexes of a program, at most (None: :data:`MAX_HEXES`, more on a
    larger plateau, :data:`PLATEAU`); ``go_on``: (``soft``, ``window``, ``gain``): past the time ``soft``
    (``time.perf_counter()``) the steps go on, up to ``deadline``, only while the minimum rose by at least ``gain``
    over the last ``window`` seconds (None: they go on to ``deadline``). Returns (V', info) with ``tries`` (rounds:
    the worst hexes' vertices split into :func:`vertex_groups`, one program each, solved on the kernel's threads),
    ``programs`` (solved), ``steps`` (kept, one per group), ``part_steps`` (of them, kept at a part of the
    program's move, :data:`STEP_PARTS`), ``hexes`` (the cap on a round's hexes at the end), ``min_before``,
    ``min_after``, ``past_soft`` (seconds from ``soft`` to the end of the last round, 0 if it ended before or
    without ``go_on``), ``splits`` (rounds whose largest group was split in two, :data:`SPLIT_VERTICES`)."""
    from functools import partial

    from ..kernel.pool import run_all, threads
    from . import kernels as lo

    V = np.array(V, dtype=np.float64, copy=True)
    H = np.ascontiguousarray(H, dtype=np.int64)
    N = V.shape[0]
    proj, _, _, _, size = vertex_freedoms(V, H, movable, boundary, 1.0)
    cell_sj = lo.hex_minima(V, H)
    info = {"steps": 0, "part_steps": 0, "tries": 0, "programs": 0, "hexes": 0, "past_soft": 0.0, "splits": 0,
            "min_before": float(cell_sj.min()) if cell_sj.size else np.inf}
    if H.shape[0] == 0:
        info["min_after"] = info["min_before"]
        return V, info
    allowed = np.zeros(N, dtype=bool)
    # the hexes near the minimum use the band even above ``band_below`` (only their vertices move here)
    allowed[H[cell_sj < max(band_below, info["min_before"] + 2 * span)].ravel()] = True
    ref, _, width = band_limits(V, movable, boundary, proj, allowed)
    banded = np.isfinite(width)
    if boundary is not None:
        # boundary vertices without a band stay where they are: a step in the tangent plane leaves a curved surface
        bv = boundary.vertices
        proj[bv[~banded[bv]]] = 0.0
    w, U = np.linalg.eigh(proj)
    fixed = {"B": U * (w > 0.5)[:, None, :],  # (N, 3, 3): the vertex's freedom, zero columns where it has none
             "dims": (w > 0.5).astype(np.float64), "size": size, "banded": banded, "width": width,
             "floor": np.minimum(hex_edge_ratio(V, H), RATIO_FLOOR)}
    can = (w > 0.5).any(axis=1)
    floor_kept = (1.0 - RATIO_SLACK) * fixed["floor"]

    # how far each banded vertex is from the input surface, curve or corner (its nearest point ``ref``)
    off = np.zeros(N)
    if banded.any():
        bidx = np.flatnonzero(banded)
        off[bidx] = np.sqrt(((V[bidx] - ref[bidx]) ** 2).sum(axis=1))

    delta = DELTA
    split = threads() > 1
    k_now = MAX_HEXES if max_hexes is None else int(max_hexes)
    clock, reached = [time.perf_counter()], [info["min_before"]]  # the minimum after each round, and when
    while info["tries"] < max_tries and delta >= DELTA_MIN:
        now = time.perf_counter()
        if deadline is not None and now > deadline:
            break
        m = float(cell_sj.min())
        if target is not None and m >= target:
            break
        if go_on is not None and now > go_on[0]:
            # past the soft end: on while the last ``window`` seconds gained at least ``gain``
            soft, window, gain = go_on
            then = reached[max(bisect.bisect_right(clock, now - window) - 1, 0)]
            if m - then < gain:
                break
        if max_hexes is None:
            # as many as the plateau at the minimum, if more (and never fewer than before in these steps)
            k_now = max(k_now, min(PLATEAU_HEXES, int(np.count_nonzero(cell_sj < m + PLATEAU))))
        k = min(k_now, cell_sj.size)
        low = np.argpartition(cell_sj, k - 1)[:k]
        low = low[cell_sj[low] < m + span]
        vmask = np.zeros(N, dtype=bool)
        vmask[H[low].ravel()] = True
        vmask &= can
        if not vmask.any():
            break
        # one program per group of vertices no hex joins, each lifting its own least sample (solved side by side
        # on the kernel's threads); the group with the lowest hex (the lead) sets the trust region
        groups = vertex_groups(vmask, H)
        if split and groups[0][0].size > SPLIT_VERTICES:
            # the largest group in two, side by side on two threads (its program alone held one thread a round)
            vmask &= ~split_layer(V, H[groups[0][1]], groups[0][0], vmask, info["tries"])  # its own hexes
            groups = vertex_groups(vmask, H)
            info["splits"] += 1
        least = [float(cell_sj[hx].min()) for _, hx in groups]
        lead = int(np.argmin(least))
        # each group's program built where it is solved: the building (Python, holding the interpreter's lock)
        # of one overlaps the solving (HiGHS, letting go of it) of another
        built = run_all([partial(_built_and_solved, (V, H, verts, hx, lg, fixed, off, ref, delta, boundary), deadline)
                         for (verts, hx), lg in zip(groups, least)])
        programs, results = [p for p, _ in built], [r for _, r in built]
        info["tries"] += 1
        info["programs"] += len(programs)
        parts = _take_steps(V, H, programs, [r.x if r.status == 0 else None for r in results], fixed, cell_sj, ref,
                            off, boundary, floor_kept)
        info["steps"] += int(np.count_nonzero(parts))
        info["part_steps"] += int(np.count_nonzero((parts > 0) & (parts < 1.0)))
        lead_part = float(parts[lead])
        delta = next_delta(delta, lead_part)
        clock.append(time.perf_counter())
        reached.append(float(cell_sj.min()))
        # each round's gain is the difference of two minima in a row
        if len(reached) > PATIENCE and sum(np.diff(reached[-1 - PATIENCE:])) < MIN_GAIN:
            break
    info["hexes"] = int(k_now)
    if go_on is not None:  # until the last round's end
        info["past_soft"] = max(clock[-1] - go_on[0], 0.0)
    info["min_after"] = float(cell_sj.min())
    return V, info


def _program(V, H, verts, hx, m, fixed, off, ref, delta, boundary):
    """The linear program of one group of vertices ``verts`` moving (module docstring) with the hexes ``hx`` around
    them, whose least sample is ``m``: a dict of its arrays for :func:`_solve` and :func:`_take_steps`."""
    from scipy.sparse import coo_matrix, diags

    N = V.shape[0]
    B, dims, size, banded, width, floor = (fixed[k] for k in ("B", "dims", "size", "banded", "width", "floor"))
    col = np.full(N, -1, dtype=np.int64)
    col[verts] = np.arange(verts.size)
    nv = 3 * verts.size
    Hx = H[hx]
    X = V[Hx]
    nh = hx.size
    # the samples: t - grad . dx <= sj
    sj, g = sample_gradients(X)
    K = sj.shape[1]
    vid = np.broadcast_to(Hx[:, None, :], (nh, K, 8)).ravel()
    row = np.broadcast_to(np.arange(nh * K).reshape(nh, K, 1), (nh, K, 8)).ravel()
    r, c, v = _rows(-g.reshape(-1, 3), vid, col, B, row)
    rows, cols, vals, rhs = [r, np.arange(nh * K)], [c, np.full(nh * K, nv)], [v, np.ones(nh * K)], [
        (1.0 - KEEP) * (sj.ravel() - m)]
    n_rows = nh * K
    # low Bernstein coefficients (of the split where they are near 0, :func:`held_coefficients`):
    # -grad . dx <= b / 2 (each row scaled by its hex's largest coefficient)
    least, scale, (hh, bl, db) = held_coefficients(X, BERNSTEIN_LOW)
    if hh.size:
        coef = -(db / scale[hh, None, None])  # (P, 8, 3)
        rowp = n_rows + np.arange(hh.size)
        r, c, v = _rows(coef.reshape(-1, 3), Hx[hh].ravel(), col, B, np.repeat(rowp, 8))
        rows.append(r), cols.append(c), vals.append(v)
        rhs.append(0.5 * bl / scale[hh])
        n_rows += hh.size
    # edge floors: |e_i|^2 >= f^2 |e_j|^2 for the pairs near it, -grad . dx <= |e_i|^2 - f^2 |e_j|^2
    e = X[:, _E[:, 1]] - X[:, _E[:, 0]]
    l2 = (e * e).sum(axis=2)
    f2 = (floor[hx] * 1.02) ** 2
    pairs = np.argwhere(l2[:, :, None] < 4.0 * f2[:, None, None] * l2[:, None, :])
    if pairs.size:
        hh, i, j = pairs.T
        nrm = l2[hh, j]
        rowp = n_rows + np.arange(hh.size)
        for vtx, sgn, vec in ((Hx[hh, _E[i, 1]], -2.0, e[hh, i]), (Hx[hh, _E[i, 0]], 2.0, e[hh, i]),
                              (Hx[hh, _E[j, 1]], 2.0 * f2[hh], e[hh, j]), (Hx[hh, _E[j, 0]], -2.0 * f2[hh], e[hh, j])):
            sg = np.broadcast_to(sgn, hh.shape)
            r, c, v = _rows(vec * (sg / nrm)[:, None], vtx, col, B, rowp)
            rows.append(r), cols.append(c), vals.append(v)
        rhs.append(np.maximum(l2[hh, i] - f2[hh] * nrm, 0.0) / nrm)
        n_rows += hh.size
    # the band: a vertex's distance from its nearest point of the input surface, curve or corner, linearized, at
    # most the width (no farther out where it is past it already); a trial vertex left outside goes back in
    # (:func:`_take_steps`)
    bvs = verts[banded[verts]]
    out = bvs[off[bvs] > 1e-3 * width[bvs]]
    if out.size:
        u = (V[out] - ref[out]) / off[out, None]
        rowp = n_rows + np.arange(out.size)
        r, c, v = _rows(u, out, col, B, rowp)
        rows.append(r), cols.append(c), vals.append(v)
        rhs.append(np.maximum(width[out] - off[out], 0.0))
        n_rows += out.size
    # the vertices of a hex with a coefficient near 0 (r of its largest) move by at most NEAR_ZERO_STEP sqrt(r) of
    # their edge length: the program holds that coefficient to first order only, and the second order, of the
    # step squared, took it below 0 (kitten_with_bifur_3: r 5e-6, every step refused down to 1e-4 of the edge
    # length; the steps stopped at 0.277, with this at 0.296-0.331)
    rel = np.maximum(least, 0.0) / scale
    rv = np.ones(N)
    np.minimum.at(rv, Hx.ravel(), np.repeat(rel, 8))
    dv = np.minimum(delta, NEAR_ZERO_STEP * np.sqrt(rv[verts]))
    # scaled for the solver: each move in units of its trust region (bounds +-1, or 0 where the vertex has no such
    # direction), t as its gain over m (HiGHS's dual simplex cycled for seconds on the unscaled program of a 4^3
    # grid near 0.996); entries below 1e-12 of the largest are rounding noise of zero gradients
    lim = np.append((dv * size[verts])[:, None].repeat(3, axis=1).ravel(), 1.0)
    Aub = coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                     shape=(n_rows, nv + 1)).tocsr() @ diags(lim)
    Aub.data[np.abs(Aub.data) < 1e-12 * np.abs(Aub.data).max()] = 0.0
    Aub.eliminate_zeros()
    on = np.append(dims[verts].ravel(), 1.0)
    Aub, b_ub = binding_rows(Aub, np.concatenate(rhs), on[:-1], nh * K)
    bounds = np.column_stack([-on, on])
    bounds[-1] = (-np.inf, np.inf)
    cost = np.zeros(nv + 1)
    cost[-1] = -1.0
    return {"verts": verts, "hx": hx, "m": m, "bvs": bvs, "lim": lim, "A": Aub, "b": b_ub, "bounds": bounds,
            "cost": cost}


def _built_and_solved(args, deadline):
    """(program, HiGHS's result): :func:`_program` of ``args``, then :func:`_solve`."""
    p = _program(*args)
    return p, _solve(p, deadline)


def _solve(p, deadline):
    """HiGHS on program ``p`` of :func:`_program`, for at most ``LP_SECONDS`` (and not past ``deadline``)."""
    from scipy.optimize import linprog

    left = LP_SECONDS if deadline is None else max(min(LP_SECONDS, deadline - time.perf_counter()), 0.01)
    return linprog(p["cost"], A_ub=p["A"], b_ub=p["b"], bounds=p["bounds"], method=LP_METHOD,
                   options={"time_limit": left, **LP_OPTIONS})


def _take_steps(V, H, programs, xs, fixed, cell_sj, ref, off, boundary, floor_kept):
    """The moves ``xs`` of the ``programs`` of :func:`_program` (None: not solved) taken where they hold: for each, the
    first of :data:`STEP_PARTS` whose hexes' least sample is above the program's ``m``, every hex valid and above
    its edge floor. The groups' vertices and hexes are disjoint, so one trial mesh serves them all. V, ``cell_sj``,
    ``ref`` and ``off`` are updated in place; returns the part kept of each (0.0: refused)."""
    from .kernels import hex_minima

    width = fixed["width"]
    parts = np.zeros(len(programs))
    moves = {}
    for i, (p, x) in enumerate(zip(programs, xs)):
        if x is not None:
            nv = 3 * p["verts"].size
            moves[i] = np.einsum("vad,vd->va", fixed["B"][p["verts"]], (p["lim"][:nv] * x[:nv]).reshape(-1, 3))
    for part in STEP_PARTS:
        if not moves:
            break
        W = V.copy()
        for i, D in moves.items():
            W[programs[i]["verts"]] += part * D
        bvs = np.concatenate([programs[i]["bvs"] for i in moves])
        if bvs.size:
            # back into the band where the polytope let a vertex out: toward its nearest point of the input surface,
            # curve or corner (the nearest point of every point between stays the same)
            C = boundary.closest(W, bvs)[bvs]
            d = W[bvs] - C
            dn = np.sqrt((d * d).sum(axis=1))
            cap = np.maximum(width[bvs], off[bvs])
            over = dn > cap
            W[bvs[over]] = C[over] + (cap[over] / dn[over])[:, None] * d[over]
            dn[over] = cap[over]
        hx = np.concatenate([programs[i]["hx"] for i in moves])
        Hx = np.ascontiguousarray(H[hx])
        new = hex_minima(W, Hx)
        ok_edge = hex_edge_ratio(W, Hx) >= floor_kept[hx]
        at_h, at_b = 0, 0
        for i in list(moves):
            p = programs[i]
            nh, nb = p["hx"].size, p["bvs"].size
            sl, bl = slice(at_h, at_h + nh), slice(at_b, at_b + nb)
            at_h, at_b = at_h + nh, at_b + nb
            if bool(new[sl].min() > p["m"]) and bool(ok_edge[sl].all()):
                V[p["verts"]] = W[p["verts"]]
                cell_sj[p["hx"]] = new[sl]
                if nb:
                    ref[p["bvs"]], off[p["bvs"]] = C[bl], dn[bl]
                parts[i] = part
                del moves[i]
    return parts
