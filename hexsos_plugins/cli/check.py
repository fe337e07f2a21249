"""``hexsos check | convert | demo``: the commands that check a mesh and write the result arrays.

Each handler returns the exit code; library errors propagate to :func:`hexsos_plugins.cli.main`, which turns them
into one line on stderr and exit code 2.
"""

from __future__ import annotations

import json
import os
import sys
import time


from .common import Progress, add_check_options, read_mesh

__all__ = ["add_parsers"]


def _read_and_check(path, args):
    """Read ``path`` (flipping a left-handed type on request) and check every 3-D cell with the command's
    options; the scaled Jacobian rides along (``result.scaled_jacobian``)."""
    from ..certify import check
    from ..kernel import threads_for

    with threads_for(args.jobs):  # the orientation pass and the scaled Jacobian on the kernel's threads too
        mesh, orient = read_mesh(path, args.fix_orientation, folded=args.folds)
        bar = Progress("checking", enabled=args.progress)
        try:
            result = check(mesh.points, mesh.cells, method=args.method, relaxation=args.relaxation, progress=bar,
                           jobs=args.jobs, processes=args.processes, scheduler=args.scheduler, quality=True)
        finally:  # the bar's line ends before the report or an error's line
            bar.close()
    return mesh, orient, result


def _header(path, mesh) -> str:
    by = mesh.counts_by_type()
    cells = ", ".join(f"{n} {t}" for t, n in by.items())
    skipped = getattr(mesh, "skipped", {}) or {}
    extra = ("; not checked: " + ", ".join(f"{n} {t}" for t, n in skipped.items())) if skipped else ""
    if set(by) == {"hexahedron"}:
        return f"{path}: {by['hexahedron']} hexahedra, {mesh.points.shape[0]} points{extra}"
    return f"{path}: {mesh.n_cells} cells ({cells}), {mesh.points.shape[0]} points{extra}"


def _cmd_check(args) -> int:
    mesh, orient, result = _read_and_check(args.mesh, args)
    warnings = []
    if args.output:
        from ..io import write

        warnings = write(mesh.to_meshio(cell_data=result.cell_data()), args.output)
    pictures = _pictures(args, mesh, result)
    if args.json:
        d = result.to_dict()
        d["file"] = args.mesh
        d["orientation"] = orient + (" (flipped)" if orient.startswith(("left-handed", "mirrored")) else "")
        d["not_checked"] = dict(getattr(mesh, "skipped", {}) or {})
        if args.output:
            d["output"] = args.output
        d["pictures"] = pictures
        d["warnings"] = warnings
        print(json.dumps(d))
    else:
        print(_header(args.mesh, mesh))
        if orient.startswith(("left-handed", "mirrored")):
            print(f"orientation: {orient}, flipped (--fix-orientation)")
        print(result.summary())
        for path in ([args.output] if args.output else []) + pictures:
            print(f"wrote {path}")
        for w in warnings:
            sys.stderr.write(f"hexsos: warning: {w}\n")
    return 0 if result.counts()["valid"] == len(result) else 1


def _pictures(args, mesh, result) -> list:
    out = []
    if not (getattr(args, "screenshot", None) or getattr(args, "histogram", None)):
        return out
    from .. import viz

    if getattr(args, "screenshot", None):
        out.append(viz.screenshot(mesh.points, mesh.cells, result, args.screenshot,
                                  title=f"{os.path.basename(args.mesh)}: " + _one_line(result)))
    if getattr(args, "histogram", None):
        out.append(viz.histogram(result, args.histogram, title=f"{os.path.basename(args.mesh)}: " + _one_line(result)))
    return out


def _one_line(result) -> str:
    c = result.counts()
    what = "hexes" if c["hexes"] == c["cells"] else "cells"
    twice = int((result.repeated_cells >= 0).sum())  # a solver would count them twice: said, not dropped
    return (f"{c['cells']} {what}, {c['invalid']} invalid ({c['invalid_inside_only']} inside only), "
            f"{c['undecided']} undecided" + (f", {twice} written twice" if twice else ""))


def _cmd_convert(args) -> int:
    from ..io import write

    mesh, orient, result = _read_and_check(args.input, args)
    warnings = write(mesh.to_meshio(cell_data=result.cell_data()), args.output)
    if args.json:
        d = result.to_dict()
        d.update({"input": args.input, "output": args.output, "warnings": warnings})
        print(json.dumps(d))
    else:
        print(f"{args.input} -> {args.output}: {_one_line(result)}")
    for w in warnings if not args.json else []:
        sys.stderr.write(f"hexsos: warning: {w}\n")
    return 0


def _cmd_demo(args) -> int:
    from ..certify import check
    from ..examples import demo_mesh
    from ..io.mesh import HexMesh

    t0 = time.perf_counter()
    points, hexes, info = demo_mesh()
    gen = time.perf_counter() - t0
    result = check(points, hexes, method=args.method, relaxation=args.relaxation, jobs=args.jobs,
                   processes=args.processes, scheduler=args.scheduler, quality=True)
    out = args.output
    if out is None:
        out = os.path.join(os.getcwd(), "hexsos-demo.vtu")
    from ..io import write

    mesh = HexMesh.from_arrays(points, hexes)
    warnings = write(mesh.to_meshio(cell_data=result.cell_data()), out)
    m = info["inside_only_hex"]
    picture = None
    if not args.no_picture:
        from ..errors import DependencyError
        from ..viz import screenshot

        try:
            picture = screenshot(points, hexes, result, os.path.splitext(out)[0] + ".png",
                                 title="hexsos demo: " + _one_line(result))
        except DependencyError as exc:  # pyvista is the optional 'viz' extra
            warnings.append(f"no picture: {exc}")
    if args.json:
        d = result.to_dict()
        d.update({"output": out, "picture": picture, "inside_only_hex": m, "generated_seconds": round(gen, 3),
                  "warnings": warnings})
        print(json.dumps(d))
        return 0
    u, v, w = result.argmin[m]
    print("hexsos demo: a ring of hexahedra meshed by Gmsh, damaged on purpose (two vertices pushed through")
    print(f"their neighbours; one boundary face distorted), {len(result)} hexes, generated in {gen:.2f} s\n")
    print(result.summary())
    print(f"\nhex {m} is what corner checks miss: det J is {result.corner_min_det[m]:.6g} or more at its 8 corners,")
    print(f"but its minimum is {result.min_det[m]:.6g} at (u, v, w) = ({u:.6f}, {v:.6f}, {w:.6f}) (proven: "
          f"{'invalid' if result.status[m] == 0 else 'not proven invalid'}).")
    print(f"\nwrote {out} (cell arrays hexsos_min_det, hexsos_lower_bound, hexsos_argmin, hexsos_status, "
          "hexsos_corner_min_det, hexsos_scaled_jacobian); open it in ParaView or Gmsh")
    if picture:
        print(f"wrote {picture}: invalid hexes red, the one that folds inside only magenta, black spheres where "
              "det J is smallest")
    for wmsg in warnings:
        sys.stderr.write(f"hexsos: warning: {wmsg}\n")
    return 0


def _add_folds(p) -> None:
    """``--folds`` of ``check`` and ``convert``."""
    p.add_argument("--folds", action="store_true",
                   help="read every shared face for cells written in the other handedness than their neighbours, "
                        "which fold over them though each is valid on its own (as the Gmsh panel's Check, the "
                        "ParaView check filter and hexsos repair do; about a second per million cells). Without "
                        "it the faces are read when some cell is negative at its centre")


def add_parsers(sub) -> None:
    """Add ``check``, ``convert`` and ``demo`` to ``sub`` (an ``argparse`` sub-parsers action)."""
    p = sub.add_parser("check", help="prove every cell valid or invalid, with its minimum det J and where it occurs",
                       description="Check every 3-D cell of MESH (tetrahedra, pyramids, wedges, hexahedra, linear and "
                                   "quadratic): exact minimum of det J over the reference element, its location, a "
                                   "proven verdict (valid / invalid / undecided), and the corner scaled Jacobian.")
    p.add_argument("mesh", metavar="MESH", help="a mesh file (any format meshio reads, e.g. .vtu .vtk .msh .mesh)")
    p.add_argument("-o", "--output", metavar="OUT", help="write the mesh with the result arrays added")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the summary")
    p.add_argument("--fix-orientation", action="store_true",
                   help="flip the cells written in the mirrored node order before checking: a type whose cells are "
                        "all negatively oriented (a file that mirrors that type's node order), a block or part "
                        "whose faces meet their neighbours' the mirrored way round")
    _add_folds(p)
    p.add_argument("--screenshot", metavar="PNG",
                   help="render the mesh coloured by min det J, invalid hexes highlighted, argmin points as spheres")
    p.add_argument("--histogram", metavar="PNG", help="plot the histogram of min det J per hex")
    add_check_options(p)
    p.set_defaults(func=_cmd_check)

    p = sub.add_parser("convert", help="read any mesh format, check it, and write any format with the results added",
                       description="Convert IN to OUT (formats from the extensions), adding the check's cell arrays; "
                                   "every cell block, point, cell and field data of IN is kept where OUT's format "
                                   "can hold it (a warning names what it cannot).")
    p.add_argument("input", metavar="IN", help="the mesh to read (any format meshio reads, plus tolerant variants)")
    p.add_argument("output", metavar="OUT", help="the mesh to write (.vtu .vtk .msh .mesh ...)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--fix-orientation", action="store_true",
                   help="flip the cells written in the mirrored node order (see check)")
    _add_folds(p)
    add_check_options(p)
    p.set_defaults(func=_cmd_convert)

    p = sub.add_parser("demo", help="generate a damaged hex mesh with Gmsh, check it and write the annotated mesh",
                       description="Generate a ring mesh with Gmsh, damage it deterministically (corner inversions "
                                   "and one hex that folds inside while all its corners are positive), check it and "
                                   "write the result.")
    p.add_argument("-o", "--output", metavar="OUT", help="where to write the annotated mesh (default ./hexsos-demo.vtu)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the summary")
    p.add_argument("--no-picture", action="store_true", help="do not render OUT's picture (.png beside OUT)")
    add_check_options(p)
    p.set_defaults(func=_cmd_demo)
