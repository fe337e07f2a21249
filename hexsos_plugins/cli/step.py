"""``hexsos step MESH --displacement ARRAY``: the certified largest safe fraction of a displacement field.

Exit code 0 when the whole step is proven safe (t* = 1), 1 when it is not (t* < 1 is printed), 2 on bad input.
"""

from __future__ import annotations

import json

import numpy as np

from .common import read_mesh
from ..errors import InvalidInputError

__all__ = ["add_parser"]


def displacement_of(mesh, name):
    """The point-data vector array ``name`` of the mesh as read, as (N, 3) floats (2 components: z = 0)."""
    pd = getattr(mesh.source, "point_data", {}) or {}
    if name not in pd:
        have = ", ".join(f"{k} {np.shape(v)}" for k, v in pd.items()) or "none"
        raise InvalidInputError(f"--displacement: expected a point-data array named {name!r}, found: {have}")
    D = np.asarray(pd[name])
    if D.ndim != 2 or D.shape[0] != len(mesh.points) or D.shape[1] not in (2, 3) or D.dtype.kind not in "iuf":
        raise InvalidInputError(f"--displacement {name}: expected a real vector array of shape "
                                f"({len(mesh.points)}, 3), found shape {D.shape} and dtype {D.dtype}")
    D = D.astype(np.float64)
    if D.shape[1] == 2:
        D = np.column_stack([D, np.zeros(len(D))])
    return D


def _line(path, r) -> str:
    if r.t == 1.0:
        return f"{path}: the whole step is proven safe (t* = 1) for all {r.cell_t.size} cells"
    head = f"{path}: safe step t* = {r.t:.9g} of the displacement ({r.cell_t.size} cells)"
    w = r.witness
    if w is None:
        return head + "; no loss of validity proven past it"
    u, v, s = w["point"]
    return head + (f"; cell {w['cell']} is proven invalid at t = {w['t']:.9g} (det J = {w['det']:.3g} at "
                   f"({u:.6g}, {v:.6g}, {s:.6g}))")


def _cmd_step(args) -> int:
    from ..certify.safe_step import safe_step

    mesh, _ = read_mesh(args.mesh, args.fix_orientation)
    D = displacement_of(mesh, args.displacement)
    # every cell's own fraction only when it is written (-o); else the mesh's t* alone (faster)
    r = safe_step(mesh.points, mesh.cells, D, rtol=args.rtol, jobs=args.jobs, per_cell=bool(args.output))
    if args.output:
        from ..io import write

        write(mesh.to_meshio(cell_data={"hexsos_safe_step": r.cell_t}), args.output)
    if args.json:
        d = r.to_dict()
        d["file"] = args.mesh
        d["displacement"] = args.displacement
        if args.output:
            d["output"] = args.output
        print(json.dumps(d))
    else:
        print(_line(args.mesh, r))
        if args.output:
            print(f"wrote {args.output} (cell array hexsos_safe_step: each cell's proven safe fraction)")
    return 0 if r.t == 1.0 else 1


def add_parser(sub) -> None:
    """Add ``step`` to ``sub`` (an ``argparse`` sub-parsers action)."""
    p = sub.add_parser("step", help="the certified largest fraction of a displacement that keeps every cell valid",
                       description="For the point-data vector array ARRAY of MESH (a displacement, e.g. a solver's "
                                   "output), the largest t* in [0, 1] such that every cell of points + t * ARRAY is "
                                   "proven valid for every t in [0, t*], and a witness (cell, point, t) just past t* "
                                   "where det J <= 0 is proven. Exit code 0 when the whole step is safe, 1 otherwise.")
    p.add_argument("mesh", metavar="MESH", help="a mesh file with a point-data vector array")
    p.add_argument("--displacement", required=True, metavar="ARRAY", help="the point-data array to step along")
    p.add_argument("-o", "--output", metavar="OUT", help="write the mesh with the cell array hexsos_safe_step")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the summary")
    p.add_argument("--rtol", type=float, default=2.0**-24, help="relative width to which t* is resolved "
                                                                 "(default 2^-24)")
    p.add_argument("--fix-orientation", action="store_true", help="flip the cells of a left-handed type first")
    p.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="threads in the compiled kernel (0: one per core, the default)")
    p.set_defaults(func=_cmd_step)
