"""What every ``hexsos`` subcommand shares: the progress bar, the run options, reading a mesh for a command.

The command modules (:mod:`.cli_check`, :mod:`.cli_repair`, ...) import from here; :mod:`.cli` imports the
command modules and assembles the parser. Nothing here imports a command module, so there is no circle.
"""

from __future__ import annotations

import sys
import time

__all__ = ["Progress", "fail", "add_check_options", "add_run_options", "read_mesh"]


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


def fail(msg: str, code: int = 2) -> int:
    sys.stderr.write(f"hexsos: error: {msg}\n")
    return code


def add_check_options(p):
    p.add_argument("--method", choices=("auto", "sos"), default="auto",
                   help="auto: Bernstein bounds, SOS only where the bracket stays open (default); "
                        "sos: the SOS relaxation on every hex, as the paper")
    p.add_argument("--relaxation", choices=("quad2", "paper"), default="quad2",
                   help="SOS relaxation (default quad2: order 2 with u(1-u) >= 0 ...; paper: section 4.2)")
    add_run_options(p)


def add_run_options(p):
    """--jobs, --processes, --scheduler, --progress / --no-progress (every command that runs the kernel)."""
    p.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="threads in the compiled kernel (0: one per core, the default; 1 with --processes or "
                        "--scheduler, whose workers run one each)")
    p.add_argument("--processes", type=int, default=1, metavar="N",
                   help="worker processes, each running the kernel (0: one per core; default 1: none)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on a Dask cluster, e.g. tcp://host:8786 (needs the 'dask' extra)")
    p.add_argument("--progress", dest="progress", action="store_true", default=None,
                   help="show a progress bar on stderr even when it is not a terminal")
    p.add_argument("--no-progress", dest="progress", action="store_false", help="never show a progress bar")


def resolve_run_options(args):
    """The default of --jobs: every core in this process; one where processes or a cluster do the work (one
    thread per worker, no oversubscription), and for the paper's repair, whose --jobs counts processes."""
    if getattr(args, "jobs", 1) is None:
        workers = getattr(args, "processes", 1) != 1 or getattr(args, "scheduler", None)
        args.jobs = 1 if workers or getattr(args, "method", None) == "paper" else 0
    return args


def announce_compilation(args) -> bool:
    """For a command that runs the kernel: say on stderr when the kernel is about to be compiled just in time (the
    compiled extension missing or built from other source), so that the wait is not a mystery."""
    if not hasattr(args, "jobs"):
        return False
    from ..kernel import compiles_at_first_use

    if not compiles_at_first_use():
        return False
    sys.stderr.write("hexsos: compiling the kernel just in time, once (one to two minutes, then cached): the compiled "
                     "extension is not installed for this source; pip install builds it\n")
    sys.stderr.flush()
    return True


def read_mesh(path, fix_orientation: bool):
    """Read ``path``; cells written in the mirrored node order are an error naming them, unless
    ``fix_orientation``, which flips exactly those. Mirrored: every cell of a type negatively oriented (the file
    mirrors that type's node order), or the cells that :meth:`~hexsos_plugins.io.mesh.Mesh.mirrored_cells` finds
    by the faces they share and by blocks (a mirrored region beside a right-handed one, a block written
    mirrored). Returns ``(mesh, orientation)`` with orientation ``"right-handed"``, ``"mixed"``, ``"left-handed
    (TYPES)"`` or ``"mirrored (COUNTS)"``; the last two are flipped."""
    import numpy as np

    from ..cells.elements import CELL_TYPES
    from ..errors import LeftHandedMeshError
    from ..io import read

    mesh = read(path)
    det = mesh.centre_det()  # one pass for both
    overall, per_type = mesh.orientation_and_types(det)
    left = [t for t, o in per_type.items() if o == "left-handed"]
    mirrored = mesh.mirrored_cells(det)
    for t in left:
        mirrored[mesh.cell_types == CELL_TYPES.index(t)] = False
    if not left and not mirrored.any():
        return mesh, overall
    counts = mesh.counts_by_type()
    some = {t: int(np.count_nonzero(mirrored[mesh.cell_types == CELL_TYPES.index(t)])) for t in counts}
    some = {t: k for t, k in some.items() if k}
    said = []
    if left:
        said.append(", ".join(f"all {counts[t]} {t} cells" for t in left) + " are negatively oriented (det J < 0 at "
                    "their centres; the file uses the mirrored node order)")
    if some:
        rows = np.flatnonzero(mirrored)
        shown = ", ".join(map(str, rows[:5])) + (", ..." if len(rows) > 5 else "")
        said.append(" and ".join(f"{k} of the {counts[t]} {t} cells" for t, k in some.items())
                    + f" (cells {shown}) are written in the mirrored node order: det J < 0 at their centres, and "
                    "their faces meet their neighbours' the wrong way round or their block is negative throughout)")
    if not fix_orientation:
        raise LeftHandedMeshError(f"{path} is {'partly mirrored' if some else 'left-handed'}: {'; '.join(said)}. "
                                  "Pass --fix-orientation to flip them")
    flipped = mesh.flipped(cell_types=left or None, cells=mirrored)
    if not some:
        return flipped, f"left-handed ({', '.join(left)})"
    which = [f"all {t}" for t in left] + [f"{k} {t}" for t, k in some.items()]
    return flipped, f"mirrored ({', '.join(which)} cells)"
