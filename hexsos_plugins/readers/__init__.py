"""Reading mesh files: meshio, VTK's and Gmsh's own readers, a numpy fast path for binary MSH, and tolerant
readers for the variants of published datasets that meshio 5.3.5 rejects.

``read(path)`` returns a :class:`~hexsos_plugins.mesh.Mesh`; ``read_meshio(path)`` the whole file as a
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
:mod:`._common`     format names, meshio's output captured, node-order corrections of meshio's formats
=================== ============================================================================================

Which reader reads what, in the order tried (the first that succeeds wins; measured with
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
(see :mod:`._common` for where meshio's own order differs and how it is corrected); a file whose cells are
mirrored is delivered mirrored, so that :meth:`Mesh.orientation <hexsos_plugins.mesh.Mesh.orientation>`
reports it.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import meshio

from ..errors import MeshFormatError, MeshReadError, UnsupportedFormatError
from ..mesh import Mesh
from ._common import (
    _READ_ALIASES,
    _ext_formats,
    _few_exts,
    _meshio_read,
    _name,
    _ParseError,
    _reader_formats,
    _short,
    fix_read_order,
    supported_extensions,
)
from .gmsh22_data import read_gmsh22_data
from .gmsh_api import read_gmsh_api
from .legacy_vtk import read_legacy_vtk, recheck_vtk51_tetra
from .medit import read_medit_text
from .msh_binary import read_msh_binary
from .vtk_api import read_vtk_api

__all__ = ["read", "read_meshio", "supported_extensions", "readers_for"]


def _read_formats(path: Path, file_format) -> list:
    if file_format is not None:
        fmt = _READ_ALIASES.get(str(file_format).lower(), str(file_format).lower())
        if fmt not in _reader_formats():
            known = ", ".join(sorted(_reader_formats()))
            raise UnsupportedFormatError(f"{path}: expected a meshio format name, found file_format={file_format!r}; "
                                         f"known: {known}")
        return [fmt]
    ext, fmts = _ext_formats(path)
    if not fmts:
        shown = f"extension '{ext}'" if ext else "no extension"
        raise UnsupportedFormatError(
            f"{path}: cannot tell the mesh format from {shown}; expected one of {_few_exts()}, "
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


def _head(path: Path, n=256) -> bytes:
    with open(path, "rb") as f:
        return f.read(n)


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


# -------------------------------------------------------------------------------------------------- the readers
def _via_meshio(path: Path, fmt: str):
    mesh, log = _meshio_read(path, fmt)
    skipped = [m for m in log if "cannot handle" in m]
    if skipped:
        raise _ParseError("meshio skipped cells it cannot read: " + "; ".join(skipped))
    fix_read_order(mesh, fmt)
    if fmt == "vtk":
        mesh = recheck_vtk51_tetra(path, mesh)
    return mesh


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


def readers_for(path, fmt: str) -> list:
    """``[(who, function(path) -> meshio.Mesh), ...]``: the readers tried for ``path`` read as ``fmt``, in order."""
    p = Path(path)
    out = []
    if fmt == "gmsh":
        head = _head(p)
        if _msh_binary(head):
            out.append(("numpy", read_msh_binary))
        out.append(("meshio", lambda q: _via_meshio(q, "gmsh")))
        gmsh_api = [("gmsh", read_gmsh_api)] if head.lstrip().startswith(b"$MeshFormat") else []
        tolerant = [("hexsos", lambda q: read_gmsh22_data(q.read_bytes(), q))]
        # MSH 2 keeps a physical tag per element, which Gmsh's reader can only give per entity: tolerant first
        out.extend(tolerant + gmsh_api if _msh_version(head).startswith("2") else gmsh_api + tolerant)
    elif fmt == "vtu":
        if _vtk_worth(p):
            out.append(("vtk", lambda q: read_vtk_api(q, legacy=False)))
        out.append(("meshio", lambda q: _via_meshio(q, "vtu")))
    elif fmt == "vtk":
        if _legacy_ascii(_head(p)) and _vtk_worth(p):
            out.append(("vtk", lambda q: read_vtk_api(q, legacy=True)))
        out.append(("meshio", lambda q: _via_meshio(q, "vtk")))
        out.append(("hexsos", lambda q: read_legacy_vtk(q.read_bytes(), q)))
    elif fmt == "medit":
        out.append(("meshio", lambda q: _via_meshio(q, "medit")))
        out.append(("hexsos", lambda q: read_medit_text(q.read_bytes(), q)))
    else:
        out.append(("meshio", lambda q, f=fmt: _via_meshio(q, f)))
    return out


def read_meshio(path, *, file_format=None) -> meshio.Mesh:
    """The whole file as a ``meshio.Mesh`` (cell blocks in VTK node order), through the readers of :func:`read`."""
    mesh, _, _ = _read_any(path, file_format)
    return mesh


def read(path, *, file_format=None) -> Mesh:
    """Read a mesh file and return its checkable 3-D cells as a :class:`~hexsos_plugins.mesh.Mesh` (the whole
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
        raise MeshFormatError(f"{p}: the file is empty (0 bytes), expected a {_name(fmts[-1])} mesh")
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
            except _ParseError as exc:
                failures.append((fmt, who, str(exc)))
                broken = broken or (who == "numpy" and "declines" not in str(exc))
                continue
            except (Exception, SystemExit) as exc:  # a malformed file must end in a typed error, whatever breaks
                failures.append((fmt, who, f"unexpected content ({type(exc).__name__}: {_short(exc, 160)})"))
                continue
            if mesh is not None:
                return mesh, fmt, who
    # Prefer hexsos's own message (it names the line); keep meshio's short reason alongside.
    fmt = failures[-1][0] if failures else fmts[-1]
    ours = ([m for f, who, m in failures if who == "numpy" and "declines" not in m]
            or [m for f, who, m in failures if who == "hexsos"])
    theirs = [m for f, who, m in failures if who == "meshio"]
    if ours:
        msg = ours[-1] + (f" (meshio: {_short(theirs[-1], 160)})" if theirs else "")
    elif theirs:
        msg = f"meshio: {theirs[-1]}"
        gm = [m for f, who, m in failures if who == "gmsh" and "session of its own" not in m]
        if gm:
            msg += f" ({_short(gm[-1], 160)})"
    else:
        msg = "; ".join(m for _, _, m in failures) or "unknown error"
    tried = " or ".join(_name(f) for f in fmts)
    raise MeshFormatError(f"{p}: could not read the file as {tried}: {msg}")
