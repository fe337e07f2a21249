"""``hexsos gmsh MESH`` / ``hexsos-gmsh MESH`` / ``python -m gmsh_plugin MESH``: the Gmsh GUI with the hexsos panel.

Opens MESH (any format Gmsh reads: .msh, .vtk, .mesh, .unv, ...) in Gmsh, with the ONELAB panel "hexsos"
(Check and Repair buttons, parameters, results; see :mod:`gmsh_plugin.panel`).

Without a display (``-nopopup``, Gmsh's own flag, or no ``DISPLAY``, or the GUI cannot start) it runs the check
headless (or the repair, with ``--auto-action repair``), prints the summary, posts the views and, with
``-o FILE.pos`` / ``FILE.msh``, writes them.

Exit codes: 0 every hex proven valid (headless / ``--exit-after``; a GUI session that is closed normally also
returns 0), 1 some hex invalid or undecided (or a repair that did not succeed), 2 bad input or another error
(one line on stderr, no traceback), 130 interrupted.
"""

from __future__ import annotations

import argparse
import os
import sys

from hexsos_plugins import __version__
from hexsos_plugins.errors import HexsosError, MeshReadError, NoHexahedraError

__all__ = ["main", "build_parser", "add_arguments", "run"]

PROG = "hexsos-gmsh"
DESCRIPTION = ("Open a mesh in the Gmsh GUI with the hexsos panel: check every 3-D element (exact min det J, where "
               "it occurs, a proven verdict; tetrahedra, pyramids, prisms, hexahedra, linear and quadratic) and "
               "repair the mesh.")


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2 (argparse's default prints the usage too)
        sys.stderr.write(f"{PROG}: error: {message}\n")
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description=DESCRIPTION)
    add_arguments(p)
    return p


def add_arguments(p) -> None:
    """The options of the Gmsh door, on ``p`` (this module's parser, or ``hexsos gmsh``'s)."""
    p.add_argument("mesh", metavar="MESH", nargs="?",
                   help="a mesh file in any format Gmsh reads (.msh .vtk .mesh .unv ...)")
    p.add_argument("--demo", action="store_true",
                   help="instead of MESH, load hexsos's demo mesh (a damaged Gmsh ring, one hex invalid inside only)")
    p.add_argument("-nopopup", "--nopopup", dest="nopopup", action="store_true",
                   help="no GUI: check (or --auto-action) headless, print the summary, exit 0 if all valid else 1")
    p.add_argument("-o", "--output", metavar="FILE",
                   help="write the hexsos views to FILE after the check (headless or --exit-after): .pos holds all; "
                        ".msh holds the mesh and the element data, the argmin points go to FILE-argmin.pos")
    p.add_argument("--method", choices=("auto", "sos"), default="auto", help="check method (default auto)")
    p.add_argument("--relaxation", choices=("quad2", "paper"), default="quad2", help="SOS relaxation (default quad2)")
    p.add_argument("--repair-method", choices=("optimize", "paper"), default="optimize",
                   help="repair: optimize (untangle, raise the minimum scaled Jacobian, certify; default) or paper "
                        "(the paper's Algorithms 1 and 2)")
    p.add_argument("--boundary", choices=("slide", "fixed", "free"), default=None,
                   help="repair: boundary nodes slide on the input's surface (default for optimize), stay fixed, "
                        "or move freely (default for paper)")
    p.add_argument("--min-sj", type=float, default=None, metavar="TARGET",
                   help="repair: stop raising the quality once every cell reaches this scaled Jacobian "
                        "(default: as high as it goes)")
    p.add_argument("--rho", type=float, default=200.0, help="repair (paper): averaging weight (default 200)")
    p.add_argument("--margin", type=float, default=None, help="repair: relative det J margin (default: repair's)")
    p.add_argument("--pin-boundary", action="store_true", help="repair: keep boundary nodes fixed")
    p.add_argument("--max-iter", type=int, default=100, help="repair: iterations (default 100)")
    p.add_argument("--auto-action", choices=("check", "repair"),
                   help="press this button once the GUI is up (headless: what to run; default check)")
    p.add_argument("--screenshot", metavar="PNG",
                   help="with the GUI: save the graphics window (seen obliquely) once --auto-action has run; "
                        "without --auto-action, the picture of the model as opened, and the GUI closes")
    p.add_argument("--exit-after", action="store_true",
                   help="with the GUI: close it once --auto-action has run (and the screenshot is saved)")
    p.add_argument("--version", action="version", version=f"{PROG} (hexsos) {__version__}")


def _no_display() -> bool:
    if sys.platform.startswith(("win", "darwin")):
        return False
    return not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _open(gmsh, args):
    """Load MESH (or the demo) into Gmsh; raises MeshReadError on a file Gmsh cannot open."""
    if args.demo:
        from hexsos_plugins.examples import demo_mesh

        from gmsh_plugin.model import add_hex_mesh

        points, hexes, _ = demo_mesh()
        add_hex_mesh(points, hexes, model="hexsos-demo")
        return "hexsos demo"
    path = args.mesh
    if not os.path.exists(path):
        raise MeshReadError(f"{path}: no such file")
    if os.path.isdir(path):
        raise MeshReadError(f"{path}: is a directory, expected a mesh file")
    try:
        gmsh.open(path)
    except Exception as exc:  # Gmsh raises plain Exception with its last error
        msg = " ".join(str(exc).split()) or "Gmsh could not read it"
        raise MeshReadError(f"{path}: Gmsh could not open it: {msg} (Gmsh reads .msh .vtk .mesh .unv ...; "
                            "convert other formats first, e.g. hexsos convert IN OUT.msh)") from None
    return path


def _print_result(label, result, out=None):
    out = out or sys.stdout
    hx = result.extra.get("gmsh")
    print(f"{label}: {hx.describe() if hx is not None else f'{len(result)} elements'}", file=out)
    print(result.summary(), file=out)
    if hx is not None and len(result):
        print(f"worst      Gmsh element {int(hx.element_tags[result.worst])}", file=out)


def _headless(gmsh, args, label) -> int:
    from gmsh_plugin.model import check_model, repair_model, write_views

    if args.screenshot:
        sys.stderr.write(f"{PROG}: warning: no display: no screenshot\n")
    if args.auto_action == "repair":
        res = repair_model(repair_method=args.repair_method, boundary=args.boundary, min_sj=args.min_sj,
                           rho=args.rho, margin=args.margin, pin_boundary=args.pin_boundary,
                           max_iter=args.max_iter if args.repair_method == "paper" or args.max_iter < 100 else None,
                           method=args.method, relaxation=args.relaxation)
        result = res.extra["model_check"]
        print(res.summary())
        _print_result(label, result)
        ok = bool(res.success) and result.counts()["valid"] == len(result)
    else:
        result = check_model(method=args.method, relaxation=args.relaxation)
        _print_result(label, result)
        ok = result.counts()["valid"] == len(result)
    views = result.extra.get("gmsh_views", {})
    print("views: " + ", ".join(f"{gmsh.option.getString(f'View[{gmsh.view.getIndex(t)}].Name')!r} (tag {t})"
                                for t in views.values() if isinstance(t, int))
          + "".join(f"; {v}" for v in views.values() if isinstance(v, str)))
    if args.output:
        for f in write_views(args.output):
            print(f"wrote {f}")
    return 0 if ok else 1


def _gui(gmsh, args, label) -> int:
    from gmsh_plugin import panel
    from gmsh_plugin.model import model_cells, write_views

    margin = "auto" if args.margin is None else repr(args.margin)
    from hexsos_plugins.meshrepair import default_boundary

    boundary = args.boundary or default_boundary(args.repair_method)
    panel.define_parameters(method=args.method, relaxation=args.relaxation, rho=args.rho, margin=margin,
                            pin=int(args.pin_boundary), max_iter=args.max_iter, repair_method=args.repair_method,
                            boundary=boundary, min_sj="auto" if args.min_sj is None else repr(args.min_sj))
    try:
        hx = model_cells()
        gmsh.onelab.setString(panel.R_MESSAGE, [f"{label}: {hx.describe()}; press Check"])
    except NoHexahedraError as exc:  # the user may still mesh the model in the GUI
        gmsh.onelab.setString(panel.R_MESSAGE, [f"{exc}; then press Check"])
    if args.screenshot:  # an oblique view shows the hexes in depth (Gmsh opens looking down -z)
        gmsh.option.setNumber("General.Trackball", 0)
        gmsh.option.setNumber("General.RotationX", -50)
        gmsh.option.setNumber("General.RotationZ", -30)
    result = panel.event_loop(auto_action=args.auto_action, screenshot=args.screenshot, exit_after=args.exit_after)
    if args.screenshot and not args.auto_action:  # the picture of the model as opened: the GUI has closed
        print(f"wrote {args.screenshot}")
        return 0
    if args.exit_after and args.auto_action:
        error = panel.last_error()
        if error is not None:
            raise error
        if result is None:
            return 2
        after = result
        if args.auto_action == "repair":
            after = result.extra["model_check"]
            print(result.summary())
        _print_result(label, after)
        if args.screenshot:
            print(f"wrote {args.screenshot}")
        if args.output:
            for f in write_views(args.output):
                print(f"wrote {f}")
        ok = after.counts()["valid"] == len(after) and getattr(result, "success", True)
        return 0 if ok else 1
    return 0


def main(argv=None) -> int:
    """Run ``hexsos-gmsh``; returns the exit code (tests call this directly)."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help, --version, usage errors
        return int(exc.code or 0)
    return run(args)


def run(args, prog: str = PROG) -> int:
    """Run the Gmsh door with parsed ``args`` (see :func:`add_arguments`); ``prog`` names it in messages."""
    if not args.mesh and not args.demo and (args.nopopup or _no_display()):
        sys.stderr.write(f"{prog}: error: no MESH given (and no GUI to open one in)\n")
        return 2
    if args.mesh and args.demo:
        sys.stderr.write(f"{prog}: error: give MESH or --demo, not both\n")
        return 2
    try:
        import gmsh
    except ImportError:
        sys.stderr.write(f"{prog}: error: Gmsh's Python API is not installed: pip install 'hexsos[gmsh]'\n")
        return 2
    headless = args.nopopup or _no_display()
    own = not gmsh.isInitialized()
    if own:
        gmsh.initialize([PROG], readConfigFiles=not headless)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        label = _open(gmsh, args) if (args.mesh or args.demo) else "(no mesh)"
        if not headless:
            try:
                from gmsh_plugin.panel import widen_menu

                widen_menu()
                gmsh.fltk.initialize()
            except Exception:
                sys.stderr.write(f"{prog}: no display: running the check without the GUI\n")
                headless = True
        if headless:
            return _headless(gmsh, args, label)
        return _gui(gmsh, args, label)
    except HexsosError as exc:
        sys.stderr.write(f"{prog}: error: {' '.join(str(exc).split())}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write(f"{prog}: interrupted\n")
        return 130
    except MemoryError:
        sys.stderr.write(f"{prog}: error: out of memory\n")
        return 2
    except OSError as exc:
        sys.stderr.write(f"{prog}: error: {exc}\n")
        return 2
    finally:
        if own:
            gmsh.finalize()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
