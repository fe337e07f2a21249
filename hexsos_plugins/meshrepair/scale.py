"""The repair at a workable scale: a mesh whose size is far from 1 is repaired scaled by a power of two, and the
result mapped back and certified again on the numbers handed back.

The optimizer's energies divide by cell sizes cubed and squared: coordinates of 1e-60 (or 1e140) underflow (or
overflow) there, and the repair stopped on a division by zero (or ended not certified, its scaled Jacobians NaN).
Validity and the scaled Jacobian do not change under a positive scaling, and scaling by a power of two is exact
in binary floating point (within its exponent range), so the repair runs on ``points * scale`` with the
bounding-box diagonal in [1, 2); the points it did not move get the caller's numbers back, the others
``V / scale``; the kernel then certifies that mesh (the certificate is about the numbers returned, which may be
subnormal), and the success is the repair's and this check's together.

Imports :mod:`hexsos_plugins.meshrepair.result` only (the certificate is the caller's function).
"""

from __future__ import annotations

import math

import numpy as np

from .result import RepairResult, readonly

__all__ = ["SCALE_RANGE", "unit_scale", "rescaled"]

#: Meshes whose bounding-box diagonal is within [2**-SCALE_RANGE, 2**SCALE_RANGE] are repaired as they are
#: (measured: a tangled 3^3 grid was repaired and certified at every scale from 1e-30 to 1e30 and stopped on a
#: division by zero at 1e-60 and 1e-140); the others at a power-of-two scale that takes their diagonal into [1, 2)
SCALE_RANGE = 16

_DIAG_KEYS = ("max_displacement", "mean_displacement", "boundary_max_distance")


def unit_scale(points, used=None) -> float:
    """1.0, or the power of two that takes the bounding-box diagonal of ``points`` (N, 3) into [1, 2) when it is
    outside [2**-SCALE_RANGE, 2**SCALE_RANGE] (and positive and finite; anything else: 1.0, for the repair's own
    checks to refuse). ``used``: the indices of the points the cells use (a list of integer arrays), the others
    left out (a point no cell uses, at 1e60 beside unit cells, would have scaled the cells to 1e-60).

    >>> unit_scale(np.array([[0.0, 0, 0], [1, 1, 1]])), unit_scale(np.array([[0.0, 0, 0], [3e-60, 0, 0]]))
    (1.0, 4.017345110647476e+59)
    >>> unit_scale(np.array([[0.0, 0, 0], [1, 1, 1], [1e60, 0, 0]]), [np.array([0, 1])])
    1.0
    """
    try:
        P = np.asarray(points, dtype=np.float64)
        if used is not None:
            idx = np.unique(np.concatenate([np.asarray(u).ravel() for u in used] + [np.zeros(0, dtype=np.int64)]))
            if idx.size == 0 or idx.dtype.kind not in "iu" or idx[0] < 0 or idx[-1] >= P.shape[0]:
                return 1.0
            P = P[idx]
    except (TypeError, ValueError, IndexError):
        return 1.0
    if P.ndim != 2 or P.shape[0] == 0 or P.shape[1] != 3 or not np.isfinite(P).all():
        return 1.0
    with np.errstate(over="ignore"):
        ext, off = P.max(axis=0) - P.min(axis=0), 0
    if not np.isfinite(ext).all():  # sides past the largest double: halved, and the exponent one more
        ext, off = P.max(axis=0) / 2 - P.min(axis=0) / 2, 1
    big = float(ext.max())
    if not (big > 0):
        return 1.0
    mant, e_big = math.frexp(big)  # big = mant * 2**e_big, mant in [0.5, 1)
    # diag = big * |ext / big| = f * 2**(e_f + e_big), f in [0.5, 1): its exponent without forming diag
    e_f = math.frexp(mant * float(np.sqrt(((ext / big) ** 2).sum())))[1]
    e = e_f + e_big - 1 + off  # diag in [2**e, 2**(e + 1))
    if -SCALE_RANGE <= e <= SCALE_RANGE:
        return 1.0
    return math.ldexp(1.0, min(-e, 1023))  # a subnormal diagonal: as far up as a double goes


def rescaled(run, points, scale: float, callback, certify) -> RepairResult:
    """``run(points * scale, callback)``'s result mapped back to the caller's scale: the points it did not move
    are the caller's numbers, the others ``V / scale``; ``certify(V) -> (check, others, n_bad)`` proves the mesh
    handed back (its hexes' or cells' :class:`~hexsos_plugins.certify.CheckResult`, the other cells' results or
    None, the count of cells not proven valid). ``callback(entry, points)`` (the caller's) sees points at the
    caller's scale."""
    P = np.array(points, dtype=np.float64, copy=True)
    Ps = P * scale

    def back(V):
        W = np.asarray(V, dtype=np.float64) / scale
        same = (np.asarray(V) == Ps).all(axis=1)
        W[same] = P[same]
        return W

    cb = None if callback is None else (lambda entry, V: callback(entry, readonly(back(V))))
    res = run(Ps, cb)
    V = back(res.points)
    r, others, n_bad = certify(V)
    ok = bool(res.success) and n_bad == 0
    message = res.message
    if res.success and not ok:
        message = (f"repaired at {scale:g} times the input's scale and certified there, but at the input's scale "
                   f"{n_bad} cell{'s' * (n_bad != 1)} {'are' if n_bad != 1 else 'is'} not proven valid (coordinates "
                   "near the limits of floating point); the best mesh seen is returned")
    stats = dict(res.stats)

    def det(d):  # det J of a 3-D cell scales as the cube (a report: it may overflow to inf or underflow to 0)
        with np.errstate(over="ignore", under="ignore"):
            return float(np.float64(d) / scale / scale / scale)

    if "min_det_before" in stats:
        stats["min_det_before"] = det(stats["min_det_before"])
    stats["min_det_after"] = float(np.min(r.min_det)) if r.min_det.size else stats.get("min_det_after")
    stats["invalid_after"] = int((r.status == 0).sum())
    stats["undecided_after"] = int((r.status == -1).sum())
    for k in _DIAG_KEYS:
        if stats.get(k) is not None:
            stats[k] = float(stats[k] / scale)
    stats.update(success=ok, message=message, repair_scale=float(scale))
    history = [dict(h, min_det=det(h["min_det"])) if "min_det" in h else dict(h) for h in res.history]
    extra = dict(res.extra)
    if others is not None:
        extra["other_cells"] = others
    return RepairResult(points=V, success=ok, check=r, history=history, stats=stats, displacement=V - P,
                        message=message, extra=extra)
