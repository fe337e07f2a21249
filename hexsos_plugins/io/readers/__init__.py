"""Reading mesh files: meshio, VTK's and Gmsh's own readers, a numpy fast path for binary MSH, and tolerant
readers for the variants of published datasets that meshio 5.3.5 rejects.

``read(path)`` returns a :class:`~hexsos_plugins.io.mesh.Mesh`; ``read_meshio(path)`` the whole file as a
``meshio.Mesh``. Neither prints nor exits; failures raise the typed errors of :mod:`hexsos_plugins.errors`.
The input file is only ever opened for reading.

One module per reader, as meshio lays out its formats:

=================== ============================================================================================
module              reads
=================== ============================================================================================
:mod:`.msh_binary`  binary Gmsh MSH 2.2 and 4.1 with numpy (``np.frombuffer`` per block): the fast path
:mod:`.gmsh_api`    any Gmsh MSH through Gmsh's C++ reader (``gmsh.open``), where meshio fails
:mod:`.vtk_api`     ``.vtu`` and ASCII legacy ``.vtk`` through VTK's readers, where ``vtk`` is importable
:mod:`.medit`       Medit ASCII, tolerant
:mod:`.legacy_vtk`  legacy VTK (ASCII and binary, 2.0-5.1), tolerant
:mod:`.gmsh22_data` MSH 2.x with ``$ElementData`` on several blocks (meshio splits it wrongly)
:mod:`.tokens`      the tolerant readers' tokenizer
:mod:`.common`      the tolerant readers' error type, meshio's reader with its output captured
=================== ============================================================================================

Each reader is declared once below with :func:`hexsos_plugins.io.formats.register_reader`. Which reader
reads what, in the order tried (the first that succeeds wins; measured with
``python -m comparison.bench_read``):

* ``.msh`` (Gmsh): the numpy fast path for binary files (it declines anything unusual: partitions, periodic
  links, parametric nodes, ``$ElementNodeData``), then meshio, then for MSH 4 Gmsh's reader; for MSH 2 the
  tolerant ``$ElementData`` reader before Gmsh's (MSH 2 holds a physical tag per element, Gmsh's model one per
  entity: its reader declines a file where they differ). Gmsh's reader is not tried on a binary file whose
  structure the numpy reader found broken (counts beyond the end of the file, undefined tags): it sizes its
  arrays by those counts and tags (10-40 s and gigabytes on single mutated 10 kB files).
* ``.vtu``: VTK's reader (for files of :data:`VTK_MIN_BYTES` or more, or when VTK is already imported), then
  meshio.
* ``.vtk``: ASCII: VTK's reader (the same condition), then meshio, then the tolerant reader; binary: meshio, then
  the tolerant reader.
* ``.mesh``: meshio, then the tolerant Medit reader. Every other format: meshio.

Whatever reads it, a file gives the same mesh (tested for every pair of readers that read the same file): the
same points, cell blocks in VTK node order, point, cell and field data. Node orders are VTK's for every reader
(see :mod:`hexsos_plugins.io.meshio_conventions` for where meshio's own order differs and how it is corrected); a file whose cells are
mirrored is delivered mirrored, so that :meth:`Mesh.orientation <hexsos_plugins.io.mesh.Mesh.orientation>`
reports it.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import meshio
import numpy as np

from ...errors import DependencyError, MeshFormatError, MeshReadError, UnsupportedFormatError
from ..mesh import Mesh
from ..formats import (READ_ALIASES, ext_formats, few_exts, format_name, reader_formats, readers_for,
                       register_reader, supported_extensions)
from .common import ParseError, meshio_read
from ..meshio_conventions import fix_read_order, shorten, vtu_version
from .gmsh22_data import read_gmsh22_data
from .gmsh_api import read_gmsh_api
from .legacy_vtk import read_legacy_vtk, recheck_vtk51_tetra
from .medit import medit_points_float64, read_medit_text
from .msh_binary import read_msh_binary
from .vtk_api import read_vtk_api

__all__ = ["read", "read_meshio", "supported_extensions", "readers_for"]


def _read_formats(path: Path, file_format) -> list:
    if file_format is not None:
        fmt = READ_ALIASES.get(str(file_format).lower(), str(file_format).lower())
        if fmt not in reader_formats():
            known = ", ".join(sorted(reader_formats()))
            raise UnsupportedFormatError(f"{path}: expected a meshio format name, found file_format={file_format!r}; "
                                         f"known: {known}")
        return [fmt]
    ext, fmts = ext_formats(path)
    if not fmts:
        shown = f"extension '{ext}'" if ext else "no extension"
        raise UnsupportedFormatError(
            f"{path}: cannot tell the mesh format from {shown}; expected one of {few_exts()}, "
            "or pass file_format="
        )
    return fmts


def _sniff_msh(path: Path, fmts: list) -> list:
    """.msh is both Gmsh and ANSYS: a file starting with '$' is Gmsh's."""
    if set(fmts) != {"ansys", "gmsh"}:
        return fmts
    with open(path, "rb") as f:
        head = f.read(64).lstrip()
    return ["gmsh"] if head.startswith(b"$") else ["ansys", "gmsh"]


def _msh_binary(head: bytes) -> bool:
    lines = head.lstrip().split(b"\n")
    if len(lines) < 2 or lines[0].strip() != b"$MeshFormat":
        return False
    parts = lines[1].split()
    return len(parts) >= 2 and parts[1] == b"1"


def _msh_version(head: bytes) -> str:
    lines = head.lstrip().split(b"\n")
    parts = lines[1].split() if len(lines) > 1 else []
    return parts[0].decode("latin-1") if parts else ""


def _legacy_ascii(head: bytes) -> bool:
    lines = head.split(b"\n")
    return len(lines) >= 3 and lines[0].startswith(b"# vtk DataFile Version") and lines[2].strip().upper() == b"ASCII"


#: VTK's readers are used for files of at least this size, or when VTK is already imported: importing them costs
#: about 0.5 s once per process (measured), more than they save on smaller files.
VTK_MIN_BYTES = 32 * 2**20


def _vtk_worth(p: Path) -> bool:
    if "vtkmodules.vtkIOXML" in sys.modules and "vtkmodules.vtkIOLegacy" in sys.modules:
        return True
    try:
        return p.stat().st_size >= VTK_MIN_BYTES
    except OSError:
        return False


# -------------------------------------------------------------------------------------------------- the readers
# Declared once each, in the order they are tried (rank; ties: this order). See the module docstring for why.
@register_reader("gmsh", "numpy", rank=0, applies=lambda p, head: _msh_binary(head))
def _numpy_msh(path: Path, fmt: str):
    return read_msh_binary(path)


@register_reader(("gmsh", "vtu", "vtk", "*"), "meshio", rank=1)
def _meshio(path: Path, fmt: str):
    return via_meshio(path, fmt)


@register_reader("medit", "meshio", rank=1)
def _meshio_medit(path: Path, fmt: str):
    """meshio's Medit reader, with an ASCII file's coordinates read again at float64 when meshio rounded them
    (it reads 'MeshVersionFormatted 1' in single precision)."""
    mesh = via_meshio(path, fmt)
    if mesh.points.dtype != np.float64 and not _binary_medit(path):
        exact = medit_points_float64(path.read_bytes(), len(mesh.points))
        if exact is None or exact.shape[1] != mesh.points.shape[1]:
            raise ParseError("meshio read the coordinates in single precision and the 'Vertices' section could "
                             "not be read again at float64")
        mesh.points = np.ascontiguousarray(exact)
    return mesh


def _binary_medit(path: Path) -> bool:
    return path.name.lower().endswith(".meshb")


def via_meshio(path: Path, fmt: str):
    """meshio's reader, cell blocks put in VTK order, what meshio skipped said."""
    mesh, log = meshio_read(path, fmt)
    skipped = [m for m in log if "cannot handle" in m]
    if skipped:
        raise ParseError("meshio skipped cells it cannot read: " + "; ".join(skipped))
    fix_read_order(mesh, fmt, vtu_version(path) if fmt == "vtu" else (0, 1))
    if fmt == "vtk":
        mesh = recheck_vtk51_tetra(path, mesh)
    return mesh


# MSH 2 keeps a physical tag per element, which Gmsh's reader can only give per entity: the tolerant reader first
@register_reader("gmsh", "hexsos", rank=lambda head: 2 if _msh_version(head).startswith("2") else 3)
def _tolerant_msh(path: Path, fmt: str):
    return read_gmsh22_data(path.read_bytes(), path)


@register_reader("gmsh", "gmsh", rank=lambda head: 3 if _msh_version(head).startswith("2") else 2,
                 applies=lambda p, head: head.lstrip().startswith(b"$MeshFormat"))
def _gmsh_msh(path: Path, fmt: str):
    return read_gmsh_api(path)


@register_reader("vtu", "vtk", rank=0, applies=lambda p, head: _vtk_worth(p))
def _vtk_xml(path: Path, fmt: str):
    return read_vtk_api(path, legacy=False)


@register_reader("vtk", "vtk", rank=0, applies=lambda p, head: _legacy_ascii(head) and _vtk_worth(p))
def _vtk_legacy(path: Path, fmt: str):
    return read_vtk_api(path, legacy=True)


@register_reader("vtk", "hexsos", rank=2)
def _tolerant_vtk(path: Path, fmt: str):
    return read_legacy_vtk(path.read_bytes(), path)


# the text read at float64 whatever its version line: hexsos's reader first (meshio's is the fallback)
@register_reader("medit", "hexsos", rank=0, applies=lambda p, head: not _binary_medit(p))
def _tolerant_medit(path: Path, fmt: str):
    return read_medit_text(path.read_bytes(), path)


def read_meshio(path, *, file_format=None) -> meshio.Mesh:
    """The whole file as a ``meshio.Mesh`` (cell blocks in VTK node order), through the readers of :func:`read`."""
    mesh, _, _ = _read_any(path, file_format)
    return mesh


def read(path, *, file_format=None) -> Mesh:
    """Read a mesh file and return its checkable 3-D cells as a :class:`~hexsos_plugins.io.mesh.Mesh` (the whole
    mesh kept in ``source``).

    Parameters
    ----------
    path : str or PathLike
    file_format : str, optional
        A meshio format name (``"vtk"``, ``"vtu"``, ``"gmsh"``, ``"medit"``, ...); default: from the extension.

    Raises
    ------
    MeshReadError
        the file does not exist, is a directory, or cannot be opened.
    UnsupportedFormatError
        unknown extension or format name (the message lists supported extensions).
    MeshFormatError
        empty, truncated or malformed content (the message names the format tried and what was wrong).
    NoCellsError (a NoHexahedraError), InvalidInputError
        from :meth:`Mesh.from_meshio`: no checkable 3-D cell; NaN coordinates, indices out of range.
    """
    mesh, fmt, who = _read_any(path, file_format)
    m = Mesh.from_meshio(mesh, path=str(path), copy=False)
    m.file_format, m.reader = fmt, who
    return m


def _read_any(path, file_format):
    try:
        p = Path(os.fspath(path))
    except TypeError as exc:
        raise MeshReadError(f"expected a file path, found {type(path).__name__}") from exc
    if not p.exists():
        raise MeshReadError(f"{p}: no such file")
    if p.is_dir():
        raise MeshReadError(f"{p}: is a directory, expected a mesh file")
    fmts = _read_formats(p, file_format)
    try:
        size = p.stat().st_size
        with open(p, "rb"):
            pass
    except OSError as exc:
        raise MeshReadError(f"{p}: cannot be opened for reading ({exc.strerror or exc})") from exc
    if size == 0:
        raise MeshFormatError(f"{p}: the file is empty (0 bytes), expected a {format_name(fmts[-1])} mesh")
    if file_format is None:
        fmts = _sniff_msh(p, fmts)

    failures = []
    for fmt in fmts:
        broken = False  # the numpy reader found the binary structure broken (not merely unusual)
        for who, reader in readers_for(p, fmt):
            if who == "gmsh" and broken:
                # Gmsh's reader sizes its arrays by the file's (here corrupt) counts and tags: measured 10-40 s
                # and gigabytes on one mutated 10 kB file; it reads valid files the numpy reader declines
                failures.append((fmt, who, "Gmsh's reader not tried: the file's binary structure is broken"))
                continue
            try:
                mesh = reader(p)
            except ParseError as exc:
                failures.append((fmt, who, str(exc)))
                broken = broken or (who == "numpy" and "declines" not in str(exc))
                continue
            except DependencyError:  # the format's package is missing: say which, whatever the other readers say
                raise
            except (Exception, SystemExit) as exc:  # a malformed file must end in a typed error, whatever breaks
                failures.append((fmt, who, f"unexpected content ({type(exc).__name__}: {shorten(exc, 160)})"))
                continue
            if mesh is not None:
                return mesh, fmt, who
    # Prefer hexsos's own message (it names the line); keep meshio's short reason alongside.
    fmt = failures[-1][0] if failures else fmts[-1]
    ours = ([m for f, who, m in failures if who == "numpy" and "declines" not in m]
            or [m for f, who, m in failures if who == "hexsos"])
    theirs = [m for f, who, m in failures if who == "meshio"]
    # Gmsh's reader names the element type no reader knows (meshio says only "np.int32(20)"): that first
    typed = [m for f, who, m in failures if who == "gmsh" and "has no meshio cell type" in m]
    if typed:
        msg = typed[-1] + (" (hexsos reads Gmsh's elements of orders 1-5, complete and incomplete: its 3-D cells and "
                           "the triangles and quadrilaterals of those orders)")
    elif ours:
        msg = ours[-1] + (f" (meshio: {shorten(theirs[-1], 160)})" if theirs else "")
    elif theirs:
        msg = f"meshio: {theirs[-1]}"
        gm = [m for f, who, m in failures if who == "gmsh" and "session of its own" not in m]
        if gm:
            msg += f" ({shorten(gm[-1], 160)})"
    else:
        msg = "; ".join(m for _, _, m in failures) or "unknown error"
    tried = " or ".join(format_name(f) for f in fmts)
    raise MeshFormatError(f"{p}: could not read the file as {tried}: {msg}")
