"""The command line: ``hexsos check | repair | convert | demo``.

Exit codes: 0 success (for ``check``: every hex proven valid), 1 the command ran but the mesh is not
(proven) valid or a repair did not succeed, 2 bad input or another error (one line on stderr, no
traceback), 130 interrupted.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

from ._version import __version__
from .errors import HexsosError

__all__ = ["main"]


class Progress:
    """A one-line progress bar on stderr, shown when stderr is a terminal (or when forced)."""

    def __init__(self, label: str, *, enabled: bool | None = None, stream=None, min_seconds: float = 0.5):
        self.stream = stream or sys.stderr
        if enabled is None:
            enabled = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.enabled = enabled
        self.label = label
        self.t0 = time.perf_counter()
        self.min_seconds = 0.0 if enabled is True and stream is not None else min_seconds
        self._shown = False
        self._last = 0.0

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if now - self.t0 < self.min_seconds and done < total:
            return
        if now - self._last < 0.1 and done < total:
            return
        self._last = now
        frac = done / total if total else 1.0
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        self.stream.write(f"\r{self.label} [{bar}] {100 * frac:5.1f}% {done:,}/{total:,}")
        self._shown = True
        if done >= total:
            self.stream.write("\n")
        self.stream.flush()

    def close(self):
        if self._shown and self.enabled:
            self.stream.flush()


def _fail(msg: str, code: int = 2) -> int:
    sys.stderr.write(f"hexsos: error: {msg}\n")
    return code


def _add_check_options(p):
    p.add_argument("--method", choices=("auto", "sos"), default="auto",
                   help="auto: Bernstein bounds, SOS only where the bracket stays open (default); "
                        "sos: the SOS relaxation on every hex, as the paper")
    p.add_argument("--relaxation", choices=("quad2", "paper"), default="quad2",
                   help="SOS relaxation (default quad2: order 2 with u(1-u) >= 0 ...; paper: section 4.2)")
    add_run_options(p)


def add_run_options(p):
    """--jobs, --scheduler, --progress / --no-progress (shared by every command that runs the kernel)."""
    p.add_argument("--jobs", type=int, default=1, metavar="N",
                   help="worker processes (0: one per core; default 1)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on a Dask cluster, e.g. tcp://host:8786 (needs the 'dask' extra)")
    p.add_argument("--progress", dest="progress", action="store_true", default=None,
                   help="show a progress bar on stderr even when it is not a terminal")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="never show a progress bar")


def _read_mesh(path, fix_orientation: bool):
    from .io import read
    from .errors import LeftHandedMeshError

    mesh = read(path)
    orient = mesh.orientation()
    if orient == "left-handed":
        if not fix_orientation:
            raise LeftHandedMeshError(
                f"{path} is left-handed: all {mesh.hexes.shape[0]} hexes are negatively oriented (det J < 0 at "
                "their centres; the file uses the mirrored node order). Pass --fix-orientation to flip them")
        mesh = mesh.flipped()
    return mesh, orient


def _read_and_check(path, args):
    """Read ``path`` (flipping a left-handed file on request) and check it with the command's options."""
    from .certify import check

    mesh, orient = _read_mesh(path, args.fix_orientation)
    bar = Progress("checking", enabled=args.progress)
    result = check(mesh.points, mesh.hexes, method=args.method, relaxation=args.relaxation, progress=bar,
                   jobs=args.jobs, scheduler=args.scheduler)
    bar.close()
    return mesh, orient, result


def _cmd_check(args) -> int:
    mesh, orient, result = _read_and_check(args.mesh, args)
    warnings = []
    if args.output:
        from .io import write

        warnings = write(mesh.to_meshio(cell_data=result.cell_data()), args.output)
    pictures = _pictures(args, mesh, result)
    if args.json:
        d = result.to_dict()
        d["file"] = args.mesh
        d["orientation"] = orient + (" (flipped)" if orient == "left-handed" else "")
        if args.output:
            d["output"] = args.output
        d["pictures"] = pictures
        d["warnings"] = warnings
        print(json.dumps(d))
    else:
        print(f"{args.mesh}: {mesh.hexes.shape[0]} hexahedra, {mesh.points.shape[0]} points")
        if orient == "left-handed":
            print("orientation: left-handed file, hexes flipped (--fix-orientation)")
        print(result.summary())
        for path in ([args.output] if args.output else []) + pictures:
            print(f"wrote {path}")
        for w in warnings:
            sys.stderr.write(f"hexsos: warning: {w}\n")
    return 0 if result.counts()["valid"] == len(result) else 1


def _pictures(args, mesh, result) -> list:
    from . import viz

    out = []
    if getattr(args, "screenshot", None):
        out.append(viz.screenshot(mesh.points, mesh.hexes, result, args.screenshot,
                                  title=f"{os.path.basename(args.mesh)}: " + _one_line(result)))
    if getattr(args, "histogram", None):
        out.append(viz.histogram(result, args.histogram, title=f"{os.path.basename(args.mesh)}: " + _one_line(result)))
    return out


def _one_line(result) -> str:
    c = result.counts()
    return (f"{c['hexes']} hexes, {c['invalid']} invalid ({c['invalid_inside_only']} inside only), "
            f"{c['undecided']} undecided")


def _cmd_convert(args) -> int:
    from .io import write

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
    from .certify import check
    from .examples import demo_mesh
    from .mesh import HexMesh

    t0 = time.perf_counter()
    points, hexes, info = demo_mesh()
    gen = time.perf_counter() - t0
    result = check(points, hexes, method=args.method, relaxation=args.relaxation, jobs=args.jobs,
                   scheduler=args.scheduler)
    out = args.output
    if out is None:
        out = os.path.join(os.getcwd(), "hexsos-demo.vtu")
    from .io import write

    mesh = HexMesh.from_arrays(points, hexes)
    warnings = write(mesh.to_meshio(cell_data=result.cell_data()), out)
    m = info["inside_only_hex"]
    picture = None
    if not args.no_picture:
        from .errors import DependencyError
        from .viz import screenshot

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
          "hexsos_corner_min_det); open it in ParaView or Gmsh")
    if picture:
        print(f"wrote {picture}: invalid hexes red, the one that folds inside only magenta, black spheres where "
              "det J is smallest")
    for wmsg in warnings:
        sys.stderr.write(f"hexsos: warning: {wmsg}\n")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hexsos",
        description="Certified validity check and repair of hexahedral meshes (exact min det J per hex).")
    parser.add_argument("--version", action="version", version=f"hexsos {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("check", help="prove every hex valid or invalid, with its minimum det J and where it occurs",
                       description="Check every hexahedron of MESH: exact minimum of det J over the parameter cube, "
                                   "its location, and a proven verdict (valid / invalid / undecided).")
    p.add_argument("mesh", metavar="MESH", help="a mesh file (any format meshio reads, e.g. .vtu .vtk .msh .mesh)")
    p.add_argument("-o", "--output", metavar="OUT", help="write the mesh with the result arrays added")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the summary")
    p.add_argument("--fix-orientation", action="store_true",
                   help="flip the hexes of a left-handed file (all hexes negatively oriented) before checking")
    p.add_argument("--screenshot", metavar="PNG",
                   help="render the mesh coloured by min det J, invalid hexes highlighted, argmin points as spheres")
    p.add_argument("--histogram", metavar="PNG", help="plot the histogram of min det J per hex")
    _add_check_options(p)
    p.set_defaults(func=_cmd_check)

    p = sub.add_parser("convert", help="read any mesh format, check it, and write any format with the results added",
                       description="Convert IN to OUT (formats from the extensions), adding the check's cell arrays; "
                                   "every cell block, point, cell and field data of IN is kept where OUT's format "
                                   "can hold it (a warning names what it cannot).")
    p.add_argument("input", metavar="IN", help="the mesh to read (any format meshio reads, plus tolerant variants)")
    p.add_argument("output", metavar="OUT", help="the mesh to write (.vtu .vtk .msh .mesh ...)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--fix-orientation", action="store_true", help="flip the hexes of a left-handed file")
    _add_check_options(p)
    p.set_defaults(func=_cmd_convert)

    p = sub.add_parser("demo", help="generate a damaged hex mesh with Gmsh, check it and write the annotated mesh",
                       description="Generate a ring mesh with Gmsh, damage it deterministically (corner inversions "
                                   "and one hex that folds inside while all its corners are positive), check it and "
                                   "write the result.")
    p.add_argument("-o", "--output", metavar="OUT", help="where to write the annotated mesh (default ./hexsos-demo.vtu)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the summary")
    p.add_argument("--no-picture", action="store_true", help="do not render OUT's picture (.png beside OUT)")
    _add_check_options(p)
    p.set_defaults(func=_cmd_demo)

    from .cli_repair import add_parser as add_repair

    add_repair(sub)
    return parser


def main(argv=None) -> int:
    """Run the command line; returns the exit code (tests call this directly)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    try:
        return args.func(args)
    except HexsosError as exc:
        return _fail(str(exc))
    except KeyboardInterrupt:
        sys.stderr.write("hexsos: interrupted\n")
        return 130
    except MemoryError:
        return _fail("out of memory: process the mesh in smaller pieces (see --help)")
    except OSError as exc:  # e.g. permission denied writing OUT
        return _fail(f"{exc.filename or ''}: {exc.strerror or exc}".lstrip(": "))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
