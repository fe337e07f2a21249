"""The one registry of file formats, shared by the readers and the writers: meshio's format names and
extensions, hexsos's aliases and write choices, what cannot be written, and which readers read a format in which
order (:func:`register_reader`, :func:`readers_for`; each reader is declared once, in
:mod:`hexsos_plugins.io.readers`).

Imports meshio only.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import meshio

__all__ = ["FORMAT_NAMES", "READ_ALIASES", "WRITE_ALIASES", "WRITE_BY_EXT", "NO_WRITE", "COMMON_EXTS", "format_name",
           "reader_formats", "writer_formats", "ext_formats", "supported_extensions", "few_exts", "register_reader",
           "readers_for", "file_head"]

FORMAT_NAMES = {
    "vtk": "legacy VTK",
    "vtu": "VTK XML (vtu)",
    "gmsh": "Gmsh MSH",
    "medit": "Medit",
    "ansys": "ANSYS msh",
    "abaqus": "Abaqus",
    "exodus": "Exodus",
    "xdmf": "XDMF",
    "nastran": "Nastran",
    "med": "MED",
}
READ_ALIASES = {"msh": "gmsh", "gmsh22": "gmsh", "gmsh4": "gmsh", "vtk42": "vtk", "vtk51": "vtk", "mesh": "medit"}
WRITE_ALIASES = {
    "msh": "gmsh",
    "gmsh": "gmsh",
    "gmsh22": "gmsh",
    "gmsh4": "gmsh",
    "gmsh41": "gmsh",
    "vtk": "vtk42",
    "vtk42": "vtk42",
    "vtk51": "vtk42",
    "mesh": "medit",
}
WRITE_BY_EXT = {".msh": "gmsh", ".vtk": "vtk42", ".mesh": "medit", ".meshb": "medit", ".vtu": "vtu"}
NO_WRITE = {"tetgen": "TetGen writes two files (.node and .ele), which cannot be written atomically"}
COMMON_EXTS = [".vtu", ".vtk", ".msh", ".mesh", ".meshb", ".xdmf", ".inp", ".med", ".exo"]


def format_name(fmt: str) -> str:
    return FORMAT_NAMES.get(fmt, fmt)


def reader_formats() -> set:
    return {f for fmts in meshio.extension_to_filetypes.values() for f in fmts}


def writer_formats() -> set:
    try:
        from meshio._helpers import (
            _writer_map,  # private, but the only list of writers meshio has
        )

        return set(_writer_map) - set(NO_WRITE)
    except Exception:  # pragma: no cover - a later meshio
        return reader_formats() - set(NO_WRITE)


def ext_formats(path: Path) -> tuple[str, list]:
    """The longest known multi-suffix of path ('.vol.gz' before '.gz') and its meshio formats."""
    suffixes = [s.lower() for s in path.suffixes]
    for k in range(len(suffixes)):
        ext = "".join(suffixes[k:])
        if ext in meshio.extension_to_filetypes:
            return ext, list(meshio.extension_to_filetypes[ext])
    return (path.suffix.lower(), [])


def supported_extensions(*, write: bool = False) -> list:
    """File extensions hexsos can read (or, with ``write=True``, write), most common first."""
    if write:
        writable = writer_formats()
        exts = [e for e, fmts in meshio.extension_to_filetypes.items()
                if WRITE_BY_EXT.get(e, fmts[0]) in writable]
    else:
        exts = list(meshio.extension_to_filetypes)
    common = [e for e in COMMON_EXTS if e in exts]
    return common + sorted(e for e in exts if e not in common)


def few_exts(write=False) -> str:
    exts = supported_extensions(write=write)
    return ", ".join(exts[:8]) + (f" (and {len(exts) - 8} more)" if len(exts) > 8 else "")


# ------------------------------------------------------------------------------------------------- the readers
@dataclass(frozen=True)
class _Reader:
    fmt: str
    who: str
    read: Callable  # (path: Path, fmt: str) -> meshio.Mesh
    applies: Callable  # (path: Path, head: bytes) -> bool
    rank: Callable  # (head: bytes) -> int: smaller first


_READERS: list = []


def register_reader(formats, who: str, *, rank=0, applies=None):
    """Declare a reader: ``fn(path, fmt) -> meshio.Mesh`` reads the meshio formats ``formats`` (a name or a tuple;
    ``"*"``: every format without a reader of its own), tried in the order of ``rank`` (an int, or a function of the
    file's first 256 bytes; ties in the order of registration) wherever ``applies(path, head)`` holds. Returns
    ``fn`` (usable as a decorator)."""
    names = (formats,) if isinstance(formats, str) else tuple(formats)

    def add(fn):
        for fmt in names:
            _READERS.append(_Reader(fmt, who, fn, applies or (lambda path, head: True),
                                    rank if callable(rank) else (lambda head, r=rank: r)))
        return fn

    return add


def file_head(path, n: int = 256) -> bytes:
    """The first ``n`` bytes of a file (empty if it cannot be read)."""
    try:
        with open(path, "rb") as f:
            return f.read(n)
    except OSError:
        return b""


def readers_for(path, fmt: str) -> list:
    """``[(who, function(path) -> meshio.Mesh), ...]``: the readers tried for ``path`` read as ``fmt``, in order."""
    p = Path(path)
    head = file_head(p)
    entries = [r for r in _READERS if r.fmt == fmt] or [r for r in _READERS if r.fmt == "*"]
    entries = [r for r in entries if r.applies(p, head)]
    entries.sort(key=lambda r: r.rank(head))  # stable: registration order among equal ranks
    return [(r.who, (lambda q, r=r: r.read(Path(q), fmt))) for r in entries]
