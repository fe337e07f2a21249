"""``hexsos repair IN -o OUT``: untangle, raise the quality, prove every cell valid, and write the mesh.

Registered by :func:`hexsos_plugins.cli.build_parser` through :func:`add_parser`. The handler returns the exit
code: 0 every cell proven valid (and ``--min-sj`` reached), 1 the repair ran but did not prove every cell valid
(OUT is still written, with the best mesh seen) or did not reach ``--min-sj``; errors are raised as :class:`~hexsos_plugins.errors.HexsosError` (the CLI's wrapper
prints one line and exits 2).
"""

from __future__ import annotations

import json
import os
import sys
import time

import numpy as np

from ..errors import DependencyError, MeshWriteError, NoHexahedraError

__all__ = ["add_parser", "run", "other_cells"]


def add_parser(subparsers):
    """Add the ``repair`` subcommand to ``subparsers`` (an ``argparse`` sub-parsers action)."""
    from .common import add_run_options
    from ..meshrepair import DEFAULT_MARGIN, DEFAULT_RHO, SURFACE_TOLERANCE

    p = subparsers.add_parser(
        "repair", help="untangle, raise the minimum scaled Jacobian, and prove every cell valid; write the mesh",
        description="Repair IN: (1) untangle (a regularized barrier on corner Jacobians and on the Bernstein "
                    "coefficients of det J), (2) raise the minimum corner scaled Jacobian while keeping every hex "
                    "valid, (3) prove every hexahedron valid with the kernel and check every other 3-D cell. "
                    "Meshes with curved cells (order 2 and more) or without hexahedra (tetrahedra, wedges): a "
                    "barrier on det J's Bernstein coefficients moves their high-order nodes (and corners where "
                    "needed) until every coefficient is positive, then raises the curved scaled Jacobian (min / max "
                    "of det J, Bernstein-bounded); every cell is proven valid by the kernel. "
                    "--method paper runs the paper's Algorithms 1 and 2 instead. Writes OUT with everything of the "
                    "input kept, plus point data hexsos_displacement and the kernel's cell arrays after repair. "
                    "Exit 0 when every cell is proven valid (and --min-sj is reached), 1 when not (OUT holds the "
                    "best mesh seen), 2 on errors.")
    p.add_argument("mesh", metavar="IN", help="the mesh to repair (any format meshio reads); never modified")
    p.add_argument("-o", "--output", metavar="OUT", required=True,
                   help="where to write the repaired mesh (any format meshio writes; written atomically)")
    p.add_argument("--method", choices=("optimize", "paper", "auto", "sos"), default="optimize",
                   help="optimize (default): untangle, raise the quality, certify; paper: the paper's Algorithms 1 "
                        "and 2 (Table 1). auto / sos: paper, with that kernel method")
    p.add_argument("--boundary", choices=("slide", "fixed", "free"), default=None,
                   help="slide (default): boundary vertices stay on the input's boundary surface (curved meshes: "
                        "on its curved faces), feature-edge vertices on their features, feature corners fixed; "
                        "fixed: pinned; free: may move (--method paper: fixed or free, default free)")
    p.add_argument("--min-sj", type=float, default=None, metavar="TARGET",
                   help="stop raising the quality once every cell's scaled Jacobian reaches TARGET (exit 1 if it is "
                        "not reached); the vertex and joint steps try first, and where they reach it that takes "
                        "seconds (the mean stays lower than the default's). Default: as high as it goes (until the "
                        "minimum rises by less than 1e-3 in 6 rounds, or --max-iter / --time-limit)")
    p.add_argument("--local", action="store_true",
                   help="a local fix: only the vertices of the cells not proven valid and of 2 layers of cells around "
                        "them move; the rest of the mesh stays exactly as it is (default: the quality stages also "
                        "raise low cells elsewhere)")
    p.add_argument("--feature-angle", type=float, default=45.0, metavar="DEG",
                   help="--boundary slide: boundary edges whose faces' normals differ by more than DEG are feature "
                        "edges (default 45)")
    p.add_argument("--surface-tolerance", type=float, default=SURFACE_TOLERANCE, metavar="F",
                   help="--boundary slide on linear cells: how far a boundary vertex may end off the input surface, "
                        "its feature curve or its feature corner, as a fraction of its boundary edge length, and at "
                        "most 1.2%% of the bounding box's diagonal "
                        f"(default {SURFACE_TOLERANCE:g}: room to square the quads of a curved surface; 0: exactly on "
                        "it, feature corners fixed)")
    p.add_argument("--time-limit", type=float, default=None, metavar="S",
                   help="seconds for untangling and quality (default: the untangling 60 s, the quality rounds 30 s, the "
                        "last vertex steps 10 s, the joint steps 10 s and on while they gain, the last stages within "
                        "50 s of the start); the certificate always runs")
    p.add_argument("--max-iter", type=int, default=None,
                   help="most outer steps per stage (optimize: default 60 untangling steps, 80 quality rounds; "
                        "paper: most outer iterations, default 100)")
    p.add_argument("--no-fallback", dest="fallback", action="store_false",
                   help="optimize: do not finish with the paper's Algorithm 2 when the optimizer ends uncertified")
    p.add_argument("--rho", type=float, default=DEFAULT_RHO,
                   help=f"paper: weight of the repaired hexes in the vertex update (default {DEFAULT_RHO:g})")
    p.add_argument("--margin", type=float, default=None,
                   help=f"paper: relative margin c > 0, each projection asks det J(u*) >= c * h^3 (default "
                        f"{DEFAULT_MARGIN:g})")
    p.add_argument("--pin-boundary", action="store_true", help="the same as --boundary fixed")
    p.add_argument("--kernel-method", choices=("auto", "sos"), default="auto",
                   help="paper: how the kernel finds u* in the iterations (sos: the moment relaxation, slow)")
    p.add_argument("--json", action="store_true", help="print one JSON object with the statistics")
    p.add_argument("--plot", metavar="PNG", help="write the convergence plot (cells not proven valid, min det J and "
                                                 "min scaled Jacobian per step) as a PNG (needs matplotlib)")
    p.add_argument("--histogram", metavar="PNG", help="write the scaled Jacobian histogram before / after as a PNG")
    p.add_argument("--fix-orientation", action="store_true",
                   help="flip the cells written in the mirrored node order first (a left-handed file, or a block "
                        "or part of it: see hexsos check)")
    p.add_argument("--no-fidelity", dest="fidelity", action="store_false",
                   help="skip the boundary fidelity (Hausdorff distance with pymeshlab)")
    add_run_options(p)  # --jobs, --scheduler (the kernel calls), --progress
    p.set_defaults(func=run)
    return p


def other_cells(mesh) -> list:
    """The 3-D cells of a :class:`~hexsos_plugins.io.mesh.HexMesh` that are not its trilinear hexahedra, as
    (type, conn) in VTK node order: from ``mesh.cells`` when the reader provides it, else from the meshio
    blocks of ``mesh.source`` (meshio's linear and quadratic 3-D types keep VTK's node order)."""
    from ..cells.elements import ELEMENTS

    blocks = getattr(mesh, "cells", None)
    if blocks is None:
        blocks = [(b.type, b.data) for b in mesh.source.cells]
    out = []
    for name, conn in blocks:
        if name in ELEMENTS and name != "hexahedron":
            out.append((name, np.asarray(conn, dtype=np.int64)))
    return out


def _same_file(a, b) -> bool:
    try:
        return os.path.exists(b) and os.path.samefile(a, b)
    except OSError:
        return False


def run(args) -> int:
    """The handler of ``hexsos repair``; returns the exit code."""
    from .common import Progress, read_mesh
    from ..meshrepair import repair

    if _same_file(args.mesh, args.output):
        raise MeshWriteError(f"{args.output}: is the input file; the input is never modified, give another OUT")
    pngs = [x for x in (args.plot, args.histogram) if x]
    for png in pngs:
        if _same_file(args.mesh, png):
            raise MeshWriteError(f"{png}: is the input file; give another PNG path")
    for target in [args.output] + pngs:  # fail now, not after a long repair
        directory = os.path.dirname(os.path.abspath(target))
        if not os.path.isdir(directory):
            raise MeshWriteError(f"{target}: cannot write, the directory {directory} does not exist")
        if not os.access(directory, os.W_OK):
            raise MeshWriteError(f"{target}: cannot write, the directory {directory} is not writable")
    mesh, orient = read_mesh(args.mesh, args.fix_orientation, folded=True)  # the repair refuses a folded mesh
    from ..meshrepair.curved import needs_curved

    curved = args.method == "optimize" and needs_curved(mesh.hexes, other_cells(mesh))
    if mesh.n_hexes == 0 and not curved:
        found = ", ".join(f"{n} {t}" for t, n in mesh.counts_by_type().items())
        raise NoHexahedraError(f"{args.mesh}: repair moves the nodes of hexahedral meshes (linear tetrahedra, prisms "
                               f"and pyramids ride along; quadratic cells keep their nodes): expected 8-node "
                               f"hexahedra, found {found}; `hexsos check` reports on every cell")
    cells = other_cells(mesh)
    method, kernel_method = args.method, args.kernel_method
    if method in ("auto", "sos"):
        method, kernel_method = "paper", method
    from ..meshrepair import resolve_boundary

    boundary = resolve_boundary(args.boundary, method, args.pin_boundary)
    if method == "optimize":
        if curved:
            from ..meshrepair.curvedkernels import compiles_at_first_use
        else:
            from ..meshrepair.kernels import compiles_at_first_use

        if compiles_at_first_use():  # the wait before the first progress is then not a mystery
            sys.stderr.write(f"hexsos: compiling the repair's loops, once ({'seconds' if curved else 'about a minute'}"
                             " on 2 cores, then cached for every later repair)\n")
            sys.stderr.flush()
    bar = Progress("repairing", enabled=args.progress)
    best = _Best(bar)
    try:
        with _sigterm_as_interrupt():
            if curved:  # every block in the file's order, so that the cell arrays line up
                from ..meshrepair.curved import repair_curved

                result = repair_curved(mesh.points, mesh.cells, boundary=boundary, min_sj=args.min_sj,
                                       max_iter=args.max_iter, time_limit=args.time_limit,
                                       feature_angle=args.feature_angle, progress=bar, jobs=args.jobs,
                                       scheduler=args.scheduler, callback=best)
                return _finish(args, mesh, orient, result, bar, cells)
            result = repair(mesh.points, mesh.hexes, cells=cells, method=method, boundary=boundary,
                            min_sj=args.min_sj, max_iter=args.max_iter, time_limit=args.time_limit,
                            feature_angle=args.feature_angle, fallback=args.fallback, rho=args.rho,
                            margin=args.margin, kernel_method=kernel_method, progress=bar, jobs=args.jobs,
                            scheduler=args.scheduler, callback=best, surface_tolerance=args.surface_tolerance,
                            **({"local": True} if getattr(args, "local", False) else {}))
            return _finish(args, mesh, orient, result, bar, cells)
    except KeyboardInterrupt:
        bar.close()
        return _interrupted(args, mesh, best)
    finally:  # an error's one line on stderr starts on a line of its own
        bar.close()


class _Best:
    """The repair's callback: keeps a copy of the best mesh seen so far (fewest hexes not proven valid, then
    the largest min det J), for the checkpoint written if the repair is interrupted, and names the stage under
    way and the seconds so far after the progress bar (whose count is of the cells repaired: full long before the
    quality stages end)."""

    def __init__(self, bar=None):
        from ..meshrepair import step_words

        self.key, self.points, self.entry = None, None, None
        self.bar, self.words = bar, step_words

    def __call__(self, entry, points):
        if self.bar is not None:
            self.bar.note(f"{self.words(entry)}, {time.perf_counter() - self.bar.t0:.0f} s")
        bad = entry["invalid"] + entry.get("undecided", 0) + entry.get("other_invalid", 0)
        key = (-bad, entry.get("min_sj", entry["min_det"]) if bad == 0 else entry["min_det"])
        if self.key is None or key > self.key:
            self.key, self.points, self.entry = key, np.array(points), dict(entry)
        return False


class _sigterm_as_interrupt:
    """SIGTERM raises KeyboardInterrupt (like Ctrl-C) inside the block, so both leave through the same path."""

    def __enter__(self):
        import signal
        import threading

        self._old = None
        if threading.current_thread() is threading.main_thread():
            def handler(signum, frame):
                raise KeyboardInterrupt("SIGTERM")

            self._old = signal.signal(signal.SIGTERM, handler)
        return self

    def __exit__(self, *exc):
        import signal

        if self._old is not None:
            signal.signal(signal.SIGTERM, self._old)
        return False


def checkpoint_path(output: str) -> str:
    """Where an interrupted repair saves the best mesh so far: OUT with '.checkpoint' before its extension."""
    base, ext = os.path.splitext(output)
    return f"{base}.checkpoint{ext or '.vtu'}"


def _interrupted(args, mesh, best) -> int:
    """Ctrl-C or SIGTERM: OUT is not written (nor left half-written); the best mesh so far goes to a checkpoint."""
    from ..io import write

    if best.points is None:
        sys.stderr.write(f"hexsos: interrupted before the first repair iteration finished; {args.output} was not "
                         "written and nothing was changed\n")
        return 130
    path = checkpoint_path(args.output)
    write(mesh.with_points(best.points).to_meshio(point_data={"hexsos_displacement": best.points - mesh.points}),
          path)
    e = best.entry
    sys.stderr.write(f"hexsos: interrupted; {args.output} was not written. The best mesh so far (outer iteration "
                     f"{e['iteration']}: {e['invalid'] + e.get('undecided', 0) + e.get('other_invalid', 0)} cells not "
                     f"proven valid) is saved in "
                     f"{path}; resume with: hexsos repair {path} -o {args.output}\n")
    return 130


def _finish(args, mesh, orient, result, bar, cells) -> int:
    """Everything after the repair: fidelity, writing OUT, the certificate of the file, the report."""
    from ..io import read, write
    from ..meshrepair import check_cells
    from ..cells.quality import scaled_jacobian, sj_text

    bar.close()

    curved = result.stats.get("method") == "curved"
    fidelity, fidelity_note, far = None, None, None
    if args.fidelity and not curved:
        from ..meshrepair.fidelity import FAR_FRACTION, boundary_fidelity

        try:
            fidelity = boundary_fidelity(mesh.points, result.points, mesh.hexes, cells=cells)
        except DependencyError as exc:
            fidelity_note = str(exc)
        if fidelity is not None and (fidelity["hausdorff_max_relative"] or 0.0) > FAR_FRACTION:
            far = (f"the boundary ended {100 * fidelity['hausdorff_max_relative']:.4g}% of the bounding-box diagonal "
                   f"from the input's (Hausdorff), more than {100 * FAR_FRACTION:g}%: the repaired mesh's shape "
                   "differs visibly from the input's there (point data hexsos_displacement shows where)")

    cell_data = dict(result.check.cell_data())
    cell_data["hexsos_scaled_jacobian"] = scaled_jacobian(result.points, mesh.cells if curved else mesh.hexes)
    if curved:
        cell_data["hexsos_curved_scaled_jacobian"] = result.extra["curved_scaled_jacobian"]
    out_mesh = mesh.with_points(result.points).to_meshio(
        cell_data=cell_data, point_data={"hexsos_displacement": result.displacement})
    warnings = write(out_mesh, args.output)

    # the certificate is about the coordinates as written: read them back, re-check if the format rounded them
    written = read(args.output)
    same = written.points.shape == result.points.shape and np.array_equal(written.points, result.points)
    if same:
        file_certified = result.success
    else:
        from ..certify import check

        if curved:
            file_certified = bool((check(written.points, written.cells).status == 1).all())
        else:
            ok_other = all((o["status"] == 1).all() for o in check_cells(written.points, cells))
            file_certified = bool((check(written.points, written.hexes).status == 1).all()) and ok_other
        warnings.append("the format rounded the coordinates; re-checked as written: "
                        + ("every cell still proven valid" if file_certified else "NOT every cell proven valid"))

    if args.plot or args.histogram:
        from ..viz import plot_histogram, plot_history
    if args.plot:
        plot_history(result.history, args.plot, title=os.path.basename(args.mesh))
    if args.histogram:
        blocks = mesh.cells if curved else [("hexahedron", mesh.hexes)] + cells
        plot_histogram(scaled_jacobian(mesh.points, blocks), scaled_jacobian(result.points, blocks), args.histogram,
                       title=os.path.basename(args.mesh))

    stats = dict(result.stats)
    target_ok = stats.get("min_sj_target_reached") is not False
    stats.update({
        "file": args.mesh,
        "output": args.output,
        "orientation": orient + (" (flipped)" if orient.startswith(("left-handed", "mirrored")) else ""),
        "hausdorff": None if fidelity is None else fidelity["hausdorff_max"],
        "hausdorff_relative": None if fidelity is None else fidelity["hausdorff_max_relative"],
        "fidelity": fidelity,
        "output_certified": file_certified,
        "history": result.history,
        "warnings": warnings + ([fidelity_note] if fidelity_note else []),
    })
    if far:
        stats["warnings"].append(far)
    if not target_ok:
        stats["warnings"].append(f"the target --min-sj {stats['min_sj_target']:g} was not reached (min scaled "
                                 f"Jacobian {sj_text(stats['min_sj_after'])})")
    for key, png in (("plot", args.plot), ("histogram", args.histogram)):
        if png:
            stats[key] = png
    if args.json:
        print(json.dumps(stats, default=_jsonable))
    else:
        n_other = sum(c.shape[0] for _, c in cells)
        if curved:
            print(f"{args.mesh}: " + ", ".join(f"{n} {t}" for t, n in mesh.counts_by_type().items())
                  + f", {mesh.points.shape[0]} points")
        else:
            print(f"{args.mesh}: {mesh.hexes.shape[0]} hexahedra" + (f", {n_other} other 3-D cells" if n_other else "")
                  + f", {mesh.points.shape[0]} points")
        if orient.startswith(("left-handed", "mirrored")):
            print(f"orientation: {orient}, flipped (--fix-orientation)")
        print(result.summary())
        if fidelity is not None:
            haus = (f"Hausdorff {fidelity['hausdorff_note']}" if fidelity["hausdorff_max"] is None else
                    f"Hausdorff max {fidelity['hausdorff_max']:.6g} ({100 * fidelity['hausdorff_max_relative']:.4g}% "
                    f"of the bbox diagonal), mean {fidelity['hausdorff_mean']:.6g}")
            print(f"boundary          {haus}; self-intersecting boundary faces "
                  f"{fidelity['self_intersecting_before']} -> {fidelity['self_intersecting_after']}")
        print(f"wrote {args.output}" + "".join(f" and {x}" for x in (args.plot, args.histogram) if x))
        for w in stats["warnings"]:
            sys.stderr.write(f"hexsos: warning: {w}\n")
    return 0 if (result.success and file_certified and target_ok) else 1


def _jsonable(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serializable: {type(x).__name__}")
