"""What every ``hexsos`` subcommand shares: the progress bar, the run options, reading a mesh for a command.

The command modules (:mod:`.check`, :mod:`.repair`, ...) import from here; :mod:`.main` imports the
command modules and assembles the parser. Nothing here imports a command module, so there is no circle.
"""

from __future__ import annotations

import sys
import time

__all__ = ["Progress", "fail", "add_check_options", "add_run_options", "read_mesh"]


class Progress:
    """A one-line progress bar on stderr, shown when stderr is a terminal (or when forced).

    Called as ``bar(done, total)``; ``bar.note(text)`` puts a word after it (the repair's stage and its seconds
    once every bad cell is repaired and the quality stages run on). The line is rewritten in place, never
    repeated, and ended by :meth:`close`."""

    def __init__(self, label: str, *, enabled: bool | None = None, stream=None, min_seconds: float = 0.5):
        self.stream = stream or sys.stderr
        if enabled is None:
            enabled = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.enabled = enabled
        self.label = label
        self.t0 = time.perf_counter()
        self.min_seconds = 0.0 if enabled is True and stream is not None else min_seconds
        self._shown = False  # a line written and not yet ended
        self._last = 0.0
        self._width = 0
        self._state = None  # (done, total) of the last call
        self._drawn_full = False
        self._note = ""

    def __call__(self, done: int, total: int) -> None:
        self._state = (done, total)
        self._draw()

    def note(self, text: str) -> None:
        """Show ``text`` after the bar (replacing the last note), at the next redraw."""
        self._note = text
        if self._state is not None:
            self._draw()

    def _draw(self) -> None:
        if not self.enabled:
            return
        done, total = self._state
        full = done >= total
        now = time.perf_counter()
        first_full = full and not self._drawn_full
        if not first_full and (now - self.t0 < self.min_seconds or now - self._last < 0.1):
            return
        self._last = now
        frac = min(done / total, 1.0) if total else 1.0
        bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
        line = f"{self.label} [{bar}] {100 * frac:5.1f}% {done:,}/{total:,}" + (f"  {self._note}" if self._note else "")
        self.stream.write("\r" + line + " " * max(self._width - len(line), 0))
        self._width = len(line)
        self._shown = True
        self._drawn_full = self._drawn_full or full
        self.stream.flush()

    def close(self):
        """End the bar's line (once); nothing if none was written."""
        if self._shown and self.enabled:
            self.stream.write("\n")
            self.stream.flush()
        self._shown = False


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


def read_mesh(path, fix_orientation: bool, *, folded: bool = False):
    """Read ``path``; cells written in the mirrored node order are an error naming them, unless
    ``fix_orientation``, which flips exactly those (:func:`hexsos_plugins.io.handedness.right_handed`, with
    ``folded`` as there: the repair reads every face for folds). Returns ``(mesh, orientation)`` with
    orientation ``"right-handed"``, ``"mixed"``, ``"left-handed (TYPES)"`` or ``"mirrored (COUNTS)"``; the last
    two are flipped."""
    from ..io import read
    from ..io.handedness import right_handed

    mesh, orientation, _ = right_handed(read(path), fix_orientation, folded=folded, name=str(path))
    return mesh, orientation
