"""``hexsos repair IN -o OUT``: repair a hex mesh until every hex is proven valid, and write it.

Registered by :func:`hexsos_plugins.cli.build_parser` through :func:`add_parser`. The handler returns the exit
code: 0 every hex proven valid, 1 the repair ran but did not prove every hex valid (OUT is still written, with
the best mesh seen); errors are raised as :class:`~hexsos_plugins.errors.HexsosError` (the CLI's wrapper
prints one line and exits 2).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile

import numpy as np

from .errors import DependencyError, MeshWriteError

__all__ = ["add_parser", "run", "plot_history"]


def add_parser(subparsers):
    """Add the ``repair`` subcommand to ``subparsers`` (an ``argparse`` sub-parsers action)."""
    from .cli_common import add_run_options
    from .meshrepair import DEFAULT_MARGIN, DEFAULT_RHO

    p = subparsers.add_parser(
        "repair", help="move vertices as little as possible until every hex is proven valid, and write the mesh",
        description="Repair IN with the paper's Algorithms 1 and 2 (per-hex projection at the exact minimizer of "
                    "det J, then averaging), until the kernel proves every hexahedron valid. Writes OUT with "
                    "everything of the input kept, plus point data hexsos_displacement and the kernel's cell "
                    "arrays after repair. Exit 0 when every hex is proven valid, 1 when not (OUT holds the best "
                    "mesh seen), 2 on errors.")
    p.add_argument("mesh", metavar="IN", help="the mesh to repair (any format meshio reads); never modified")
    p.add_argument("-o", "--output", metavar="OUT", required=True,
                   help="where to write the repaired mesh (any format meshio writes; written atomically)")
    p.add_argument("--rho", type=float, default=DEFAULT_RHO,
                   help=f"weight of the repaired hexes in the vertex update (default {DEFAULT_RHO:g}, the paper's)")
    p.add_argument("--margin", type=float, default=None,
                   help=f"relative margin c > 0: each projection asks det J(u*) >= c * h^3, h the hex's mean edge "
                        f"length (default {DEFAULT_MARGIN:g})")
    p.add_argument("--pin-boundary", action="store_true",
                   help="keep the boundary vertices (on quads of one hex only) fixed")
    p.add_argument("--max-iter", type=int, default=100, help="most outer iterations (default 100)")
    p.add_argument("--json", action="store_true", help="print one JSON object with the statistics")
    p.add_argument("--plot", metavar="PNG", help="write the convergence plot (invalid hexes and min det J per "
                                                 "iteration) as a PNG (needs matplotlib)")
    p.add_argument("--fix-orientation", action="store_true",
                   help="flip the hexes of a left-handed file (all hexes negatively oriented) first")
    p.add_argument("--no-fidelity", dest="fidelity", action="store_false",
                   help="skip the boundary fidelity (Hausdorff distance with pymeshlab)")
    p.add_argument("--method", choices=("auto", "sos"), default="auto",
                   help="how the kernel finds u* in the iterations: auto (default) or sos (the moment relaxation "
                        "on every hex checked, as the paper; slow). The final certificate always uses auto")
    add_run_options(p)  # --jobs, --scheduler (the per-hex repair steps and the checks), --progress
    p.set_defaults(func=run)
    return p


def _same_file(a, b) -> bool:
    try:
        return os.path.exists(b) and os.path.samefile(a, b)
    except OSError:
        return False


def run(args) -> int:
    """The handler of ``hexsos repair``; returns the exit code."""
    from .cli_common import Progress, read_mesh
    from .meshrepair import repair

    if _same_file(args.mesh, args.output):
        raise MeshWriteError(f"{args.output}: is the input file; the input is never modified, give another OUT")
    if args.plot and _same_file(args.mesh, args.plot):
        raise MeshWriteError(f"{args.plot}: is the input file; give another PNG path")
    for target in [args.output] + ([args.plot] if args.plot else []):  # fail now, not after a long repair
        directory = os.path.dirname(os.path.abspath(target))
        if not os.path.isdir(directory):
            raise MeshWriteError(f"{target}: cannot write, the directory {directory} does not exist")
        if not os.access(directory, os.W_OK):
            raise MeshWriteError(f"{target}: cannot write, the directory {directory} is not writable")
    mesh, orient = read_mesh(args.mesh, args.fix_orientation)
    bar = Progress("repairing", enabled=args.progress)
    best = _Best()
    try:
        with _sigterm_as_interrupt():
            result = repair(mesh.points, mesh.hexes, rho=args.rho, margin=args.margin,
                            pin_boundary=args.pin_boundary, max_iter=args.max_iter, method=args.method,
                            progress=bar, jobs=args.jobs, scheduler=args.scheduler, callback=best)
            return _finish(args, mesh, orient, result, bar)
    except KeyboardInterrupt:
        bar.close()
        return _interrupted(args, mesh, best)


class _Best:
    """The repair's callback: keeps a copy of the best mesh seen so far (fewest hexes not proven valid, then
    the largest min det J), for the checkpoint written if the repair is interrupted."""

    def __init__(self):
        self.key, self.points, self.entry = None, None, None

    def __call__(self, entry, points):
        key = (-(entry["invalid"] + entry.get("undecided", 0)), entry["min_det"])
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
    from .io import write

    if best.points is None:
        sys.stderr.write(f"hexsos: interrupted before the first repair iteration finished; {args.output} was not "
                         "written and nothing was changed\n")
        return 130
    path = checkpoint_path(args.output)
    write(mesh.with_points(best.points).to_meshio(point_data={"hexsos_displacement": best.points - mesh.points}),
          path)
    e = best.entry
    sys.stderr.write(f"hexsos: interrupted; {args.output} was not written. The best mesh so far (outer iteration "
                     f"{e['iteration']}: {e['invalid'] + e.get('undecided', 0)} hexes not proven valid) is saved in "
                     f"{path}; resume with: hexsos repair {path} -o {args.output}\n")
    return 130


def _finish(args, mesh, orient, result, bar) -> int:
    """Everything after the repair: fidelity, writing OUT, the certificate of the file, the report."""
    from .io import read, write

    bar.close()

    fidelity, fidelity_note = None, None
    if args.fidelity:
        from .fidelity import boundary_fidelity

        try:
            fidelity = boundary_fidelity(mesh.points, result.points, mesh.hexes)
        except DependencyError as exc:
            fidelity_note = str(exc)

    out_mesh = mesh.with_points(result.points).to_meshio(
        cell_data=result.check.cell_data(), point_data={"hexsos_displacement": result.displacement})
    warnings = write(out_mesh, args.output)

    # the certificate is about the coordinates as written: read them back, re-check if the format rounded them
    written = read(args.output)
    same = written.points.shape == result.points.shape and np.array_equal(written.points, result.points)
    if same:
        file_certified = result.success
    else:
        from .certify import check

        file_certified = bool((check(written.points, written.hexes).status == 1).all())
        warnings.append("the format rounded the coordinates; re-checked as written: "
                        + ("every hex still proven valid" if file_certified else "NOT every hex proven valid"))

    if args.plot:
        plot_history(result.history, args.plot, title=os.path.basename(args.mesh))

    stats = dict(result.stats)
    stats.update({
        "file": args.mesh,
        "output": args.output,
        "orientation": orient + (" (flipped)" if orient == "left-handed" else ""),
        "hausdorff": None if fidelity is None else fidelity["hausdorff_max"],
        "hausdorff_relative": None if fidelity is None else fidelity["hausdorff_max_relative"],
        "fidelity": fidelity,
        "output_certified": file_certified,
        "history": result.history,
        "warnings": warnings + ([fidelity_note] if fidelity_note else []),
    })
    if args.plot:
        stats["plot"] = args.plot
    if args.json:
        print(json.dumps(stats, default=_jsonable))
    else:
        print(f"{args.mesh}: {mesh.hexes.shape[0]} hexahedra, {mesh.points.shape[0]} points")
        if orient == "left-handed":
            print("orientation: left-handed file, hexes flipped (--fix-orientation)")
        print(result.summary())
        if fidelity is not None:
            print(f"boundary          Hausdorff max {fidelity['hausdorff_max']:.6g} "
                  f"({100 * fidelity['hausdorff_max_relative']:.4g}% of the bbox diagonal), mean "
                  f"{fidelity['hausdorff_mean']:.6g}; self-intersecting boundary quads "
                  f"{fidelity['self_intersecting_before']} -> {fidelity['self_intersecting_after']}")
        print(f"wrote {args.output}" + (f" and {args.plot}" if args.plot else ""))
        for w in stats["warnings"]:
            sys.stderr.write(f"hexsos: warning: {w}\n")
    return 0 if (result.success and file_certified) else 1


def _jsonable(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serializable: {type(x).__name__}")


def plot_history(history, path, *, title: str | None = None) -> str:
    """Write the convergence plot (the paper's Figure 11) as a PNG, atomically; returns the path.

    Hexes not proven valid per outer iteration on the left y-axis, the smallest min det J over the mesh on
    the right y-axis. Needs matplotlib (extra ``viz``); uses the Agg backend, no display.
    """
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg  # no pyplot: no global backend switch
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise DependencyError("--plot needs matplotlib: pip install 'hexsos[viz]'") from exc
    it = [h["iteration"] for h in history]
    bad = [h["invalid"] + h.get("undecided", 0) for h in history]
    md = [h["min_det"] for h in history]
    fig = Figure(figsize=(6.4, 4.0), dpi=120)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(it, bad, "-o", color="tab:blue", markersize=3)
    ax.set_xlabel("outer iteration (Algorithm 2)")
    ax.set_ylabel("hexes not proven valid", color="tab:blue")
    ax.tick_params(axis="y", labelcolor="tab:blue")
    ax.set_ylim(bottom=0)
    ax2 = ax.twinx()
    ax2.plot(it, md, "-s", color="tab:red", markersize=3)
    ax2.axhline(0.0, color="tab:red", linewidth=0.6, linestyle=":")
    ax2.set_ylabel("min det J over the mesh", color="tab:red")
    ax2.tick_params(axis="y", labelcolor="tab:red")
    ax.set_title(f"hexsos repair{': ' + title if title else ''}")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise MeshWriteError(f"{path}: cannot write the plot, the directory {directory} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=".hexsos-plot.", suffix=".png", dir=directory)
    os.close(fd)
    try:
        fig.savefig(tmp, format="png")
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise
    return path
