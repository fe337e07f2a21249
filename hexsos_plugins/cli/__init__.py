"""The command line: ``hexsos check | repair | step | convert | demo | paraview | gmsh``.

Owns: argument parsing and the one place where typed errors become one line on stderr and an exit code
(:mod:`.main`), what the commands share (:mod:`.common`: reading, progress, run options), and one module per
family of commands (:mod:`.check`: check, convert, demo; :mod:`.repair`; :mod:`.step`; :mod:`.doors`: the ParaView and Gmsh
launchers).

May import every other wing of :mod:`hexsos_plugins`; nothing of hexsos imports it but ``__main__`` and the doors'
launchers.
"""

from .main import build_parser, main

__all__ = ["main", "build_parser"]
