"""The command line: ``hexsos check | repair | step | convert | demo | paraview | gmsh``.

Exit codes: 0 success (for ``check``: every cell proven valid), 1 the command ran but the mesh is not
(proven) valid or a repair did not succeed, 2 bad input or another error (one line on stderr, no
traceback), 130 interrupted.

Each subcommand lives in its own module (:mod:`.cli_check`, :mod:`.cli_repair`) with an ``add_parser(s)``
function; this module only assembles them and turns library errors into exit codes.
"""

from __future__ import annotations

import argparse
import sys

from . import check as cli_check
from . import doors as cli_doors
from . import repair as cli_repair
from . import step as cli_step
from .._version import __version__
from .common import announce_compilation, fail, resolve_run_options
from ..errors import HexsosError

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hexsos",
        description="Certified validity check and repair of hexahedral meshes (exact min det J per hex).")
    parser.add_argument("--version", action="version", version=f"hexsos {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    cli_check.add_parsers(sub)
    cli_repair.add_parser(sub)
    cli_step.add_parser(sub)
    cli_doors.add_parsers(sub)
    return parser


def main(argv=None) -> int:
    """Run the command line; returns the exit code (tests call this directly)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help(sys.stderr)
        return 2
    cli_doors.auto_record()  # lets the ParaView plugin, loaded by hand, find this environment
    resolve_run_options(args)
    announce_compilation(args)
    try:
        return args.func(args)
    except HexsosError as exc:
        return fail(str(exc))
    except KeyboardInterrupt:
        sys.stderr.write("hexsos: interrupted\n")
        return 130
    except MemoryError:
        return fail("out of memory: process the mesh in smaller pieces (see --help)")
    except OSError as exc:  # e.g. permission denied writing OUT
        return fail(f"{exc.filename or ''}: {exc.strerror or exc}".lstrip(": "))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
