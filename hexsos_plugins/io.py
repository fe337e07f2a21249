"""Reading and writing mesh files: meshio, plus tolerant readers and workarounds for meshio 5.3.5's traps.

``read(path)`` returns a :class:`~hexsos_plugins.mesh.HexMesh`; ``write(mesh, path)`` writes a
``meshio.Mesh`` (for instance ``HexMesh.to_meshio(...)``) atomically and returns warnings for the caller.
Neither prints nor exits; failures raise the typed errors of :mod:`hexsos_plugins.errors`.

Reading
-------
meshio is tried first. When it fails (it raises all sorts of exceptions, and ``SystemExit`` on some
inputs), hexsos's own readers take over for the two text formats most hex-mesh datasets are published in:

* **Medit** ``.mesh`` (ASCII): counts on the keyword's line (``Vertices 8``) or on the next line, the keyword
  ``Quads`` for ``Quadrilaterals``, ``#`` comments, text after ``End`` or after the last section.
* **legacy VTK** ``.vtk`` (ASCII and BINARY, versions 2.0 to 5.1, ``DATASET UNSTRUCTURED_GRID``): 8-node
  cells typed 10 (VTK_TETRA) are read as hexahedra (12); voxels (11) are read as ``voxel`` blocks (which
  :class:`HexMesh` converts to VTK order); text after the data is ignored. (meshio's 5.1 reader does not
  fail on 8-node cells typed 10: it silently keeps their last 4 nodes as a tetra; a 5.x file that meshio
  returns with tetrahedra is therefore read again here.)
* **Gmsh** ``.msh`` 2.2 with ``$ElementData`` on a mesh of several cell blocks (meshio 5.3.5 splits the data
  wrongly and fails): the data sections are parsed here, the rest by meshio. Assumes element tags 1..M
  in file order, as meshio and Gmsh write them.

The input file is only ever opened for reading.

Writing (``write``)
-------------------
Atomic: the file is written to a temporary file in the target directory, then renamed over the target
(``os.replace``); on any failure the temporary file is removed and an existing target is left as it was.

* ``.msh``: Gmsh MSH **2.2, binary**. meshio's ASCII MSH with cell data cannot be read back under NumPy 2;
  meshio's MSH 4.1 writer needs ``gmsh:dim_tags`` point data, fails on meshes of several cell types
  without it, keeps one physical tag per block, and with synthesized entity tags wrote a mixed mesh its
  own reader could not read back (KeyError, measured). MSH 2.2 binary keeps
  ``gmsh:physical`` / ``gmsh:geometrical`` per element, cell and point data as ``$ElementData`` /
  ``$NodeData`` and ``[tag, dim]`` field data as ``$PhysicalNames``; Gmsh 4.15 opens it (tested).
  Data arrays must have 1, 3 or 9 components: 2 -> padded to 3, 4..8 -> padded to 9 (zeros), more ->
  split into ``name_0``, ``name_1``, ... (with a warning). Tags are written as int32.
* ``.vtk``: legacy VTK **4.2, ASCII**. meshio's default 5.1 cannot be opened by Gmsh, and Gmsh 4.15's
  legacy reader cannot read *binary* legacy VTK at all (not even the files Gmsh writes itself: it reads
  the binary block one byte early). Field data is added as a dataset-level ``FIELD`` section after the
  cell types, which VTK and meshio read as field data and Gmsh skips.
* ``.vtu``: meshio's writer (binary, zlib); field data (which meshio's writer drops) is added as a
  ``<FieldData>`` element of the grid.
* ``.mesh`` / ``.meshb`` (Medit): holds one integer reference per vertex and per element, nothing else.
  The element reference is ``medit:ref`` if present, else ``gmsh:physical``, else 1; every other cell
  array, point array and field data is dropped **with a warning naming them**. Cell types Medit cannot
  hold are skipped with a warning.
* Every format: booleans are written as int8, float16 as float32; complex/object/string arrays are
  dropped with a warning; array names with spaces get underscores in ``.vtk``; ``voxel`` blocks are
  written as ``hexahedron`` blocks. MSH, VTK and VTU have no block boundaries of their own: consecutive
  blocks of the same cell type come back from them as one block (Medit keeps them apart).
"""

from __future__ import annotations

import contextlib
import io as _stdio
import os
import re
import tempfile
import warnings as _warnings
from pathlib import Path

import meshio
import numpy as np

from .errors import (
    HexsosError,
    InvalidInputError,
    MeshFormatError,
    MeshReadError,
    MeshWriteError,
    UnsupportedFormatError,
)
from .hexahedron import VOXEL_TO_VTK
from .mesh import HexMesh, _copy_block, _copy_mesh

__all__ = ["read", "write", "supported_extensions", "read_meshio"]

_FORMAT_NAMES = {
    "vtk": "legacy VTK",
    "vtu": "VTK XML (vtu)",
    "gmsh": "Gmsh MSH",
    "medit": "Medit",
    "ansys": "ANSYS msh",
    "abaqus": "Abaqus",
    "exodus": "Exodus",
    "xdmf": "XDMF",
}
_READ_ALIASES = {"msh": "gmsh", "gmsh22": "gmsh", "gmsh4": "gmsh", "vtk42": "vtk", "vtk51": "vtk", "mesh": "medit"}
_WRITE_ALIASES = {
    "msh": "gmsh22",
    "gmsh": "gmsh22",
    "gmsh22": "gmsh22",
    "vtk": "vtk42",
    "vtk42": "vtk42",
    "vtk51": "vtk42",
    "mesh": "medit",
}
_WRITE_BY_EXT = {".msh": "gmsh22", ".vtk": "vtk42", ".mesh": "medit", ".meshb": "medit", ".vtu": "vtu"}
_NO_WRITE = {"tetgen": "TetGen writes two files (.node and .ele), which cannot be written atomically"}
_COMMON_EXTS = [".vtu", ".vtk", ".msh", ".mesh", ".meshb", ".xdmf", ".inp", ".med", ".exo"]


# ---------------------------------------------------------------------------------------------------- helpers
def _name(fmt: str) -> str:
    return _FORMAT_NAMES.get(fmt, fmt)


def _reader_formats() -> set:
    return {f for fmts in meshio.extension_to_filetypes.values() for f in fmts}


def _writer_formats() -> set:
    try:
        from meshio._helpers import _writer_map  # private, but the only list of writers meshio has

        return set(_writer_map) - set(_NO_WRITE)
    except Exception:  # pragma: no cover - a later meshio
        return _reader_formats() - set(_NO_WRITE)


def _ext_formats(path: Path) -> tuple[str, list]:
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
        writable = _writer_formats()
        exts = [e for e, fmts in meshio.extension_to_filetypes.items()
                if _WRITE_BY_EXT.get(e, fmts[0]) in writable]
    else:
        exts = list(meshio.extension_to_filetypes)
    common = [e for e in _COMMON_EXTS if e in exts]
    return common + sorted(e for e in exts if e not in common)


def _few_exts(write=False) -> str:
    exts = supported_extensions(write=write)
    return ", ".join(exts[:8]) + (f" (and {len(exts) - 8} more)" if len(exts) > 8 else "")


@contextlib.contextmanager
def _quiet():
    """Capture what meshio prints (it prints errors and warnings) and silence Python warnings."""
    out, err = _stdio.StringIO(), _stdio.StringIO()
    log = []
    with _warnings.catch_warnings():
        _warnings.simplefilter("ignore")
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                yield log
            finally:
                log.extend(_split_messages(out.getvalue() + "\n" + err.getvalue()))


def _split_messages(text: str) -> list:
    """meshio's rich console output, one message per 'Warning:' / 'Info:' / 'Error:', lines joined."""
    text = " ".join(text.split())
    if not text:
        return []
    parts = re.split(r"(?=\b(?:Warning|Info|Error):)", text)
    return [p.strip() for p in parts if p.strip()]


class _ParseError(Exception):
    """A tolerant reader's failure; becomes a MeshFormatError with the path and format."""


def _short(msg: str, limit: int = 240) -> str:
    msg = " ".join(str(msg).split())
    return msg if len(msg) <= limit else msg[: limit - 3] + "..."


# ---------------------------------------------------------------------------------------------------- reading
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


def _meshio_read(path: Path, fmt: str):
    """meshio.read with its printing captured; returns (mesh, messages) or raises _ParseError."""
    try:
        with _quiet() as log:
            mesh = meshio.read(str(path), file_format=fmt)
    except (Exception, SystemExit) as exc:
        said = [re.sub(r"^(Warning|Error):\s*", "", m) for m in log if not m.startswith("Info")]
        text = str(exc) if not isinstance(exc, SystemExit) else ""
        reason = "; ".join(x for x in [text] + said if x) or type(exc).__name__
        raise _ParseError(_short(reason)) from None
    return mesh, log


def read_meshio(path, *, file_format=None) -> meshio.Mesh:
    """The file as a ``meshio.Mesh``, through meshio or hexsos's tolerant readers (see :func:`read`)."""
    mesh, _ = _read_any(path, file_format)
    return mesh


def read(path, *, file_format=None) -> HexMesh:
    """Read a mesh file and return its hexahedra as a :class:`HexMesh` (the whole mesh kept in ``source``).

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
    NoHexahedraError, InvalidInputError
        from :meth:`HexMesh.from_meshio`: no hexahedra; NaN coordinates, indices out of range.
    """
    mesh, fmt = _read_any(path, file_format)
    hm = HexMesh.from_meshio(mesh, path=str(path))
    hm.file_format = fmt
    return hm


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
    raw = None
    for fmt in fmts:
        try:
            mesh, log = _meshio_read(p, fmt)
            skipped = [m for m in log if "cannot handle" in m]
            if skipped:
                raise _ParseError("meshio skipped cells it cannot read: " + "; ".join(skipped))
            if fmt == "vtk":
                mesh = _recheck_vtk51_tetra(p, mesh)
            return mesh, fmt
        except _ParseError as exc:
            failures.append((fmt, "meshio", str(exc)))
        tolerant = _TOLERANT.get(fmt)
        if tolerant is None:
            continue
        if raw is None:
            raw = p.read_bytes()
        try:
            mesh = tolerant(raw, p)
        except _ParseError as exc:
            failures.append((fmt, "hexsos", str(exc)))
            continue
        except (Exception, SystemExit) as exc:  # a malformed file must end in a typed error, whatever breaks
            failures.append((fmt, "hexsos", f"unexpected content ({type(exc).__name__}: {_short(exc, 160)})"))
            continue
        if mesh is not None:
            return mesh, fmt
    # Prefer hexsos's own message (it names the line); keep meshio's short reason alongside.
    fmt = failures[-1][0] if failures else fmts[-1]
    ours = [m for f, who, m in failures if who == "hexsos"]
    theirs = [m for f, who, m in failures if who == "meshio"]
    if ours:
        msg = ours[-1] + (f" (meshio: {_short(theirs[-1], 160)})" if theirs else "")
    else:
        msg = f"meshio: {theirs[-1]}" if theirs else "unknown error"
    tried = " or ".join(_name(f) for f in fmts)
    raise MeshFormatError(f"{p}: could not read the file as {tried}: {msg}")


# ------------------------------------------------------------------------------------------ text cursor
class _Cursor:
    """Walks a text (a latin-1 decoded file: character offsets are byte offsets) by tokens, lines, bytes."""

    _TOKEN = re.compile(r"\S+")

    def __init__(self, raw: bytes, comment: str | None = None):
        self.raw = raw
        self.text = raw.decode("latin-1")
        self.n = len(self.text)
        self.pos = 0
        self.comment = comment

    def lineno(self, pos=None) -> int:
        return self.text.count("\n", 0, self.pos if pos is None else pos) + 1

    def _end(self, pos) -> int:
        e = self.text.find("\n", pos)
        return self.n if e < 0 else e

    def _seg(self, pos, end) -> str:
        seg = self.text[pos:end]
        if self.comment:
            i = seg.find(self.comment)
            if i >= 0:
                seg = seg[:i]
        return seg

    def token(self):
        """(next token, its offset) skipping whitespace and comments; (None, n) at the end."""
        while self.pos < self.n:
            e = self._end(self.pos)
            m = self._TOKEN.search(self._seg(self.pos, e))
            if m:
                start = self.pos + m.start()
                self.pos += m.end()
                return m.group(), start
            self.pos = e + 1
        return None, self.n

    def peek(self):
        save = self.pos
        tok = self.token()
        self.pos = save
        return tok

    def rest_of_line(self) -> str:
        e = self._end(self.pos)
        s = self.text[self.pos:e]
        self.pos = e + 1
        return s.strip()

    def next_line(self):
        """(next non-blank line stripped, its line number) or (None, None) at the end."""
        while self.pos < self.n:
            start = self.pos
            e = self._end(self.pos)
            s = self._seg(self.pos, e).strip()
            self.pos = e + 1
            if s:
                return s, self.lineno(start)
        return None, None

    def take(self, count: int) -> list:
        """The next ``count`` tokens (fewer at the end of the text)."""
        out = []
        while len(out) < count and self.pos < self.n:
            e = self._end(self.pos)
            seg = self._seg(self.pos, e)
            toks = seg.split()
            need = count - len(out)
            if len(toks) <= need:
                out.extend(toks)
                self.pos = e + 1
            else:
                for k, m in enumerate(self._TOKEN.finditer(seg)):
                    if k == need - 1:
                        self.pos += m.end()
                        break
                out.extend(toks[:need])
        return out

    def binary(self, count: int, dtype, what: str, line: int) -> np.ndarray:
        dtype = np.dtype(dtype)
        nbytes = count * dtype.itemsize
        if self.pos + nbytes > len(self.raw):
            have = max(len(self.raw) - self.pos, 0) // dtype.itemsize
            raise _ParseError(f"expected {count} binary values for {what} (line {line}), "
                              f"found only {have} before the end of the file (truncated?)")
        arr = np.frombuffer(self.raw, dtype=dtype, count=count, offset=self.pos).copy()
        self.pos += nbytes
        if self.text.startswith("\r\n", self.pos):
            self.pos += 2
        elif self.text.startswith("\n", self.pos):
            self.pos += 1
        return arr


def _numbers(tokens: list, count: int, dtype, what: str, line: int) -> np.ndarray:
    if len(tokens) < count:
        raise _ParseError(f"expected {count} numbers for {what} (line {line}), "
                          f"found only {len(tokens)} before the end of the file (truncated?)")
    try:
        return np.array(tokens, dtype=dtype)
    except (ValueError, OverflowError):
        pass
    if np.dtype(dtype).kind in "iu":
        try:
            f = np.array(tokens, dtype=np.float64)
            if np.isfinite(f).all() and (f == np.round(f)).all():
                return f.astype(dtype)
        except (ValueError, OverflowError):
            pass
    conv = float if np.dtype(dtype).kind == "f" else int
    for t in tokens:
        try:
            conv(t)
        except (ValueError, OverflowError):
            kind = "a number" if conv is float else "an integer"
            raise _ParseError(f"expected {kind} in the data of {what} (line {line}), found {t[:40]!r}") from None
    raise _ParseError(f"could not convert the data of {what} (line {line})")  # pragma: no cover


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _make_block(cell_type: str, data, dim: int | None = None):
    """A meshio CellBlock of any type name (meshio's constructor rejects e.g. 'voxel')."""
    block = meshio.CellBlock("vertex", np.zeros((0, 1), dtype=np.int64))
    block.type = cell_type
    block.data = np.asarray(data)
    block.dim = dim if dim is not None else _DIMS.get(cell_type, 3)
    return block


_DIMS = {"vertex": 0, "line": 1, "line3": 1, "line4": 1, "triangle": 2, "quad": 2, "polygon": 2, "triangle6": 2,
         "triangle7": 2, "quad8": 2, "quad9": 2, "quad6": 2}


# ---------------------------------------------------------------------------------------------------- Medit
_MEDIT_CELLS = {
    "edges": ("line", 2),
    "triangles": ("triangle", 3),
    "quadrilaterals": ("quad", 4),
    "quads": ("quad", 4),
    "tetrahedra": ("tetra", 4),
    "prisms": ("wedge", 6),
    "pyramids": ("pyramid", 5),
    "hexahedra": ("hexahedron", 8),
    "hexaedra": ("hexahedron", 8),
}
# sections read and discarded: keyword -> numbers per entry ("d" = the dimension)
_MEDIT_SKIP = {
    "corners": 1, "requiredvertices": 1, "ridges": 1, "requirededges": 1, "requiredtriangles": 1,
    "requiredquadrilaterals": 1, "requiredtetrahedra": 1, "requiredhexahedra": 1,
    "normals": "d", "tangents": "d", "normalatvertices": 2, "tangentatvertices": 2, "tangentatedges": 3,
    "normalattrianglevertices": 3, "normalatquadrilateralvertices": 3, "vertexongeometricvertex": 2,
    "vertexongeometricedge": 3, "vertexongeometrictriangle": 4, "edgeongeometricedge": 2,
    "subdomainfrommesh": 4, "subdomainfromgeom": 4,
}
_MEDIT_KEYS = set(_MEDIT_CELLS) | set(_MEDIT_SKIP) | {"vertices", "meshversionformatted", "dimension", "end",
                                                       "identifier", "geometry"}


def _read_medit_text(raw: bytes, path) -> meshio.Mesh:
    """Medit ASCII, tolerant of 'Vertices 8' on one line, 'Quads', comments and trailing text."""
    if str(path).lower().endswith(".meshb"):
        raise _ParseError("binary Medit (.meshb) is read by meshio only")
    cur = _Cursor(raw, comment="#")
    dim = 3
    points = None
    point_ref = None
    cells, refs = [], []
    while True:
        tok, at = cur.token()
        if tok is None:
            break
        key = tok.lower()
        line = cur.lineno(at)
        if key == "end":
            break
        if key not in _MEDIT_KEYS:
            if _is_number(tok) and (points is not None or cells):
                raise _ParseError(f"expected a Medit keyword, found the number {tok[:40]!r} (line {line}): "
                                  "does the count of the section before it match its data?")
            if points is not None and cells and not _medit_keyword_follows(cur):
                break  # text appended after the data
            if points is None and not cells:
                raise _ParseError(f"expected a Medit keyword such as 'MeshVersionFormatted' or 'Vertices', "
                                  f"found {tok[:40]!r} (line {line})")
            raise _ParseError(f"expected a Medit keyword, found {tok[:40]!r} (line {line})")
        if key in ("identifier", "geometry"):
            if cur.rest_of_line() == "":
                cur.rest_of_line()
            continue
        value, vat = cur.token()
        if key in ("meshversionformatted", "dimension"):
            if value is None or not value.lstrip("+-").isdigit():
                found = "the end of the file" if value is None else repr(value[:40])
                raise _ParseError(f"expected an integer after '{tok}', found {found} (line {cur.lineno(vat)})")
            if key == "dimension":
                dim = int(value)
                if dim not in (2, 3):
                    raise _ParseError(f"expected 'Dimension' 2 or 3, found {dim} (line {cur.lineno(vat)})")
            continue
        what = "vertex" if key == "vertices" else _MEDIT_CELLS[key][0] if key in _MEDIT_CELLS else "entry"
        if value is None or not value.lstrip("+").isdigit():
            found = "the end of the file" if value is None else repr(value[:40])
            article = "an" if what[0] in "aeiou" else "a"
            raise _ParseError(f"expected {article} {what} count after '{tok}', found {found} "
                              f"(line {cur.lineno(vat) if value is not None else line})")
        count = int(value)
        if key == "vertices":
            vals = _numbers(cur.take(count * (dim + 1)), count * (dim + 1), np.float64, f"'{tok} {count}'", line)
            vals = vals.reshape(count, dim + 1)
            points = vals[:, :dim]
            point_ref = vals[:, dim].astype(np.int64)
        elif key in _MEDIT_CELLS:
            ctype, k = _MEDIT_CELLS[key]
            vals = _numbers(cur.take(count * (k + 1)), count * (k + 1), np.int64, f"'{tok} {count}'", line)
            vals = vals.reshape(count, k + 1)
            cells.append((ctype, vals[:, :k] - 1))
            refs.append(vals[:, k])
        else:
            per = dim if _MEDIT_SKIP[key] == "d" else _MEDIT_SKIP[key]
            _numbers(cur.take(count * per), count * per, np.float64, f"'{tok} {count}'", line)
    if points is None:
        raise _ParseError("expected a 'Vertices' section, found none")
    return meshio.Mesh(points, cells, point_data={"medit:ref": point_ref}, cell_data={"medit:ref": refs})


def _medit_keyword_follows(cur: _Cursor) -> bool:
    rest = cur.text[cur.pos:]
    for line in rest.splitlines():
        words = line.split("#", 1)[0].split()
        if words and words[0].lower() in _MEDIT_KEYS - {"end"}:
            return True
    return False


# ----------------------------------------------------------------------------------------------- legacy VTK
_VTK_DTYPES = {
    "unsigned_char": "u1", "char": "i1", "unsigned_short": "u2", "short": "i2", "unsigned_int": "u4",
    "int": "i4", "unsigned_long": "u8", "long": "i8", "float": "f4", "double": "f8", "vtkidtype": "i4",
    "vtktypeint8": "i1", "vtktypeuint8": "u1", "vtktypeint16": "i2", "vtktypeuint16": "u2",
    "vtktypeint32": "i4", "vtktypeuint32": "u4", "vtktypeint64": "i8", "vtktypeuint64": "u8",
    "vtktypefloat32": "f4", "vtktypefloat64": "f8",
}
# VTK cell type -> (meshio type, node count)
_VTK_CELLS = {
    1: ("vertex", 1), 3: ("line", 2), 5: ("triangle", 3), 8: ("quad", 4), 9: ("quad", 4), 10: ("tetra", 4),
    11: ("voxel", 8), 12: ("hexahedron", 8), 13: ("wedge", 6), 14: ("pyramid", 5), 21: ("line3", 3),
    22: ("triangle6", 6), 23: ("quad8", 8), 24: ("tetra10", 10), 25: ("hexahedron20", 20),
    26: ("wedge15", 15), 27: ("pyramid13", 13), 28: ("quad9", 9), 29: ("hexahedron27", 27),
    30: ("quad6", 6), 31: ("wedge12", 12), 32: ("wedge18", 18), 33: ("hexahedron24", 24),
    34: ("triangle7", 7), 35: ("line4", 4),
}
_VTK_VARIABLE = {2: "poly_vertex", 4: "poly_line", 6: "triangle_strip", 42: "polyhedron"}
_PIXEL_TO_QUAD = np.array([0, 1, 3, 2])
_VTK_WEDGE_TO_MESHIO = np.array([0, 2, 1, 3, 5, 4])


def _vtk_dtype(name: str, binary: bool, what: str, line: int):
    code = _VTK_DTYPES.get(name.lower())
    if code is None:
        raise _ParseError(f"expected a VTK data type (float, double, int, ...) in {what} (line {line}), "
                          f"found {name!r}")
    return np.dtype((">" if binary else "=") + code)


class _VtkReader:
    def __init__(self, raw: bytes):
        self.cur = _Cursor(raw)
        self.binary = False

    def values(self, count, dtype, what, line):
        if self.binary:
            arr = self.cur.binary(count, dtype, what, line)
            return arr.astype(arr.dtype.newbyteorder("="))
        return _numbers(self.cur.take(count), count, dtype.newbyteorder("="), what, line)

    def read(self) -> meshio.Mesh:
        cur = self.cur
        first = cur.rest_of_line()
        if not first.startswith("# vtk DataFile Version"):
            raise _ParseError(f"expected '# vtk DataFile Version x.x' on line 1, found {first[:40]!r}")
        cur.rest_of_line()  # title
        kind, line = cur.next_line()
        if kind is None or kind.upper() not in ("ASCII", "BINARY"):
            raise _ParseError(f"expected 'ASCII' or 'BINARY' on line 3, found {kind!r}")
        self.binary = kind.upper() == "BINARY"
        ds, line = cur.next_line()
        if ds is None or ds.split()[:1] != ["DATASET"]:
            raise _ParseError(f"expected 'DATASET UNSTRUCTURED_GRID' (line {line}), found {ds!r}")
        if ds.split()[1:2] != ["UNSTRUCTURED_GRID"]:
            raise _ParseError(f"hexsos's legacy VTK reader handles DATASET UNSTRUCTURED_GRID only, found {ds!r} "
                              f"(line {line})")
        points = conn = offsets = types = None
        point_data, cell_data, field_data = {}, {}, {}
        active, n_active = field_data, None
        while True:
            s, line = cur.next_line()
            if s is None:
                break
            words = s.split()
            key = words[0].upper()
            try:
                if key == "POINTS":
                    n = int(words[1])
                    dt = _vtk_dtype(words[2], self.binary, "POINTS", line)
                    points = self.values(3 * n, dt, f"'{s}'", line).reshape(n, 3).astype(np.float64)
                elif key == "CELLS":
                    a, b = int(words[1]), int(words[2])
                    nxt, _ = cur.peek()
                    if nxt is not None and nxt.upper() == "OFFSETS":
                        o_line, o_no = cur.next_line()
                        offsets = self.values(a, _vtk_dtype(o_line.split()[1], self.binary, "OFFSETS", o_no),
                                              f"'{o_line}'", o_no).astype(np.int64)
                        c_line, c_no = cur.next_line()
                        if c_line is None or c_line.split()[0].upper() != "CONNECTIVITY":
                            raise _ParseError(f"expected 'CONNECTIVITY' after the offsets (line {c_no}), "
                                              f"found {c_line!r}")
                        conn = self.values(b, _vtk_dtype(c_line.split()[1], self.binary, "CONNECTIVITY", c_no),
                                           f"'{c_line}'", c_no).astype(np.int64)
                    else:
                        raw = self.values(b, np.dtype(">i4" if self.binary else "i8"), f"'{s}'", line).astype(np.int64)
                        conn, offsets = _legacy_cells(raw, a, line)
                elif key == "CELL_TYPES":
                    n = int(words[1])
                    types = self.values(n, np.dtype(">i4" if self.binary else "i8"), f"'{s}'", line).astype(np.int64)
                elif key in ("POINT_DATA", "CELL_DATA"):
                    n_active = int(words[1])
                    active = point_data if key == "POINT_DATA" else cell_data
                elif key in ("SCALARS", "VECTORS", "NORMALS", "TENSORS", "TEXTURE_COORDINATES", "COLOR_SCALARS"):
                    if n_active is None:
                        raise _ParseError(f"expected POINT_DATA or CELL_DATA before {key} (line {line})")
                    name, arr = self._attribute(key, words, n_active, line)
                    if arr is not None:
                        active[name] = arr
                elif key == "LOOKUP_TABLE":
                    size = int(words[2])
                    if self.binary:
                        cur.binary(4 * size, "u1", f"'{s}'", line)
                    else:
                        _numbers(cur.take(4 * size), 4 * size, np.float64, f"'{s}'", line)
                elif key == "FIELD":
                    target = active if n_active is not None else field_data
                    for _ in range(int(words[2])):
                        name, arr = self._field_array()
                        target[name] = arr
                elif key == "METADATA":
                    self._skip_metadata()
                else:
                    if _is_number(words[0]):
                        raise _ParseError(f"expected a legacy VTK keyword, found the number {words[0][:40]!r} "
                                          f"(line {line}): does the count of the section before it match its data?")
                    if points is not None and conn is not None and types is not None:
                        break  # text appended after the data
                    raise _ParseError(f"expected a legacy VTK section (POINTS, CELLS, CELL_TYPES, ...), "
                                      f"found {s[:40]!r} (line {line})")
            except (IndexError, ValueError) as exc:
                raise _ParseError(f"could not parse the section header {s[:60]!r} (line {line}): {exc}") from None
        for what, arr in (("POINTS", points), ("CELLS", conn), ("CELL_TYPES", types)):
            if arr is None:
                raise _ParseError(f"expected a {what} section, found none")
        if len(types) != len(offsets) - 1:
            raise _ParseError(f"expected as many CELL_TYPES as CELLS, found {len(types)} types for "
                              f"{len(offsets) - 1} cells")
        for name, arr in point_data.items():
            if len(arr) != len(points):
                raise _ParseError(f"point data {name!r} has {len(arr)} values for {len(points)} points")
        for name, arr in cell_data.items():
            if len(arr) != len(types):
                raise _ParseError(f"cell data {name!r} has {len(arr)} values for {len(types)} cells")
        cells, cd = _vtk_blocks(conn, offsets, types, cell_data)
        return meshio.Mesh(points, cells, point_data=point_data, cell_data=cd, field_data=field_data)

    def _attribute(self, key, words, n, line):
        name = words[1]
        if key == "SCALARS":
            dt = _vtk_dtype(words[2], self.binary, key, line)
            ncomp = int(words[3]) if len(words) > 3 else 1
            nxt, _ = self.cur.peek()
            if nxt is not None and nxt.upper() == "LOOKUP_TABLE":
                self.cur.next_line()
        elif key == "COLOR_SCALARS":
            ncomp = int(words[2])
            dt = np.dtype("u1") if self.binary else np.dtype("f8")
        elif key == "TEXTURE_COORDINATES":
            ncomp = int(words[2])
            dt = _vtk_dtype(words[3], self.binary, key, line)
        else:
            ncomp = 9 if key == "TENSORS" else 3
            dt = _vtk_dtype(words[2], self.binary, key, line)
        arr = self.values(n * ncomp, dt, f"'{' '.join(words)}'", line)
        if key == "TENSORS":
            return name, arr.reshape(n, 3, 3)
        return name, (arr if ncomp == 1 else arr.reshape(n, ncomp))

    def _field_array(self):
        s, line = self.cur.next_line()
        while s is not None and s.split()[0].upper() == "METADATA":
            self._skip_metadata()
            s, line = self.cur.next_line()
        if s is None:
            raise _ParseError("expected a field array header 'name components tuples type', found the end of the file")
        words = s.split()
        if len(words) != 4:
            raise _ParseError(f"expected a field array header 'name components tuples type', found {s[:60]!r} "
                              f"(line {line})")
        ncomp, ntup = int(words[1]), int(words[2])
        arr = self.values(ncomp * ntup, _vtk_dtype(words[3], self.binary, "FIELD", line), f"'{s}'", line)
        return words[0], (arr if ncomp == 1 else arr.reshape(ntup, ncomp))

    def _skip_metadata(self):
        while self.cur.pos < self.cur.n:
            if self.cur.rest_of_line() == "":
                return


def _legacy_cells(raw: np.ndarray, n: int, line: int):
    """Connectivity and offsets (n+1) from the legacy 'count i0 i1 ...' list of n cells."""
    if n == 0:
        return raw[:0], np.zeros(1, dtype=np.int64)
    k = int(raw[0])
    if k > 0 and len(raw) == n * (k + 1) and (raw[:: k + 1] == k).all():
        conn = raw.reshape(n, k + 1)[:, 1:].ravel()
        return conn, np.arange(n + 1, dtype=np.int64) * k
    sizes = np.empty(n, dtype=np.int64)
    pos = 0
    for i in range(n):
        if pos >= len(raw):
            raise _ParseError(f"expected {n} cells in the CELLS list (line {line}), found only {i}")
        sizes[i] = raw[pos]
        if sizes[i] < 0:
            raise _ParseError(f"expected a node count for cell {i} in the CELLS list (line {line}), found {sizes[i]}")
        pos += sizes[i] + 1
    if pos != len(raw):
        raise _ParseError(f"the CELLS list (line {line}) holds {len(raw)} numbers, but its {n} cells use {pos}")
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    keep = np.ones(len(raw), dtype=bool)
    keep[offsets[:-1] + np.arange(n)] = False
    return raw[keep], offsets


def _vtk_blocks(conn, offsets, types, cell_data):
    """meshio cell blocks (runs of one type and size) from VTK arrays; 8-node type-10 cells become hexahedra."""
    n = len(types)
    sizes = np.diff(offsets)
    if len(offsets) and (offsets[0] != 0 or offsets[-1] != len(conn) or (sizes < 0).any()):
        raise _ParseError(f"the cell offsets do not match the connectivity ({len(conn)} node indices)")
    types = types.copy()
    types[(types == 10) & (sizes == 8)] = 12  # published files type their hexahedra as VTK_TETRA
    for t in np.unique(types):
        t = int(t)
        if t in _VTK_VARIABLE or (t not in _VTK_CELLS and t != 7):
            i = int(np.flatnonzero(types == t)[0])
            name = _VTK_VARIABLE.get(t, "unknown")
            raise _ParseError(f"cell {i} has VTK cell type {t} ({name}), which hexsos's legacy VTK reader "
                              "does not handle")
        if t != 7:
            bad = (types == t) & (sizes != _VTK_CELLS[t][1])
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise _ParseError(f"cell {i} has VTK cell type {t} ({_VTK_CELLS[t][0]}), which has "
                                  f"{_VTK_CELLS[t][1]} nodes, but it lists {int(sizes[i])}")
    if n == 0:
        return [], {}
    change = np.flatnonzero((types[1:] != types[:-1]) | (sizes[1:] != sizes[:-1])) + 1
    bounds = np.concatenate([[0], change, [n]])
    cells, cd = [], {name: [] for name in cell_data}
    for s, e in zip(bounds[:-1], bounds[1:]):
        t, k = int(types[s]), int(sizes[s])
        idx = offsets[s:e, None] + np.arange(k)
        data = conn[idx]
        if t == 7:
            cells.append(_make_block("polygon", data, 2))
        else:
            ctype = _VTK_CELLS[t][0]
            if t == 8:
                data = data[:, _PIXEL_TO_QUAD]
            elif t == 13:
                data = data[:, _VTK_WEDGE_TO_MESHIO]
            cells.append(_make_block(ctype, data))
        for name, arr in cell_data.items():
            cd[name].append(arr[s:e])
    return cells, cd


def _recheck_vtk51_tetra(path: Path, mesh: meshio.Mesh) -> meshio.Mesh:
    """meshio's VTK 5.1 reader turns an 8-node cell typed 10 into a tetra of its last 4 nodes, silently.

    When a 5.x file comes back with tetrahedra, read it again here; if the cells differ, ours are right.
    """
    if not any(b.type == "tetra" for b in mesh.cells):
        return mesh
    with open(path, "rb") as f:
        if not f.readline().startswith(b"# vtk DataFile Version 5"):
            return mesh
    try:
        ours = _read_legacy_vtk(path.read_bytes(), path)
    except Exception:
        return mesh
    same = [(b.type, len(b.data)) for b in ours.cells] == [(b.type, len(b.data)) for b in mesh.cells]
    return mesh if same else ours


def _read_legacy_vtk(raw: bytes, path) -> meshio.Mesh:
    if not raw.strip():
        raise _ParseError("the file holds only whitespace")
    return _VtkReader(raw).read()


# ---------------------------------------------------------------------------- Gmsh 2.2 with $ElementData
def _read_gmsh22_data(raw: bytes, path) -> meshio.Mesh:
    """MSH 2.x whose $ElementData meshio 5.3.5 splits wrongly over several blocks: parse the data here."""
    head = raw.lstrip()[:200].split(b"\n")
    if len(head) < 2 or head[0].strip() != b"$MeshFormat":
        raise _ParseError("expected '$MeshFormat' at the start of the file")
    parts = head[1].split()
    if not parts or not parts[0].startswith(b"2"):
        raise _ParseError(f"meshio could not read this MSH {parts[0].decode('latin-1') if parts else '?'} file")
    binary = len(parts) > 1 and parts[1] == b"1"
    start = raw.find(b"$EndElements")
    if start < 0 or raw.find(b"$ElementData", start) < 0:
        raise _ParseError("meshio could not read this MSH 2 file (and it has no $ElementData to work around)")
    sections, cuts = [], []
    pos = raw.find(b"$ElementData", start)
    while pos >= 0:
        name, idx, vals, end = _parse_gmsh_data(raw, pos, binary)
        sections.append((name, idx, vals))
        cuts.append((pos, end))
        pos = raw.find(b"$ElementData", end)
    stripped = bytearray()
    last = 0
    for a, b in cuts:
        stripped += raw[last:a]
        last = b
    stripped += raw[last:]
    fd, tmp = tempfile.mkstemp(suffix=".msh", prefix="hexsos-read-")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(bytes(stripped))
        mesh, _ = _meshio_read(Path(tmp), "gmsh")
    finally:
        with contextlib.suppress(OSError):
            os.remove(tmp)
    lengths = [len(b.data) for b in mesh.cells]
    total = sum(lengths)
    for name, idx, vals in sections:
        if len(idx) != total or not np.array_equal(np.sort(idx), np.arange(1, total + 1)):
            raise _ParseError(f"$ElementData {name!r} has {len(idx)} values for elements "
                              f"{int(idx.min()) if len(idx) else 0}..{int(idx.max()) if len(idx) else 0}, "
                              f"expected one per element 1..{total}")
        vals = vals[np.argsort(idx, kind="stable")]
        if vals.shape[1] == 1:
            vals = vals[:, 0]
        mesh.cell_data[name] = np.split(vals, np.cumsum(lengths)[:-1])
    return mesh


def _parse_gmsh_data(raw: bytes, pos: int, binary: bool):
    cur = _Cursor(raw)
    cur.pos = pos
    cur.rest_of_line()  # $ElementData
    try:
        ns = int(cur.rest_of_line())
        strings = [cur.rest_of_line().strip('"') for _ in range(ns)]
        nr = int(cur.rest_of_line())
        for _ in range(nr):
            cur.rest_of_line()
        ni = int(cur.rest_of_line())
        ints = [int(cur.rest_of_line()) for _ in range(ni)]
        ncomp, nitems = ints[1], ints[2]
    except (ValueError, IndexError):
        raise _ParseError(f"malformed $ElementData header (line {cur.lineno(pos)})") from None
    name = strings[0] if strings else f"data_{pos}"
    if binary:
        dt = np.dtype([("index", "=i4"), ("values", "=f8", (ncomp,))])
        arr = cur.binary(nitems, dt, f"$ElementData {name!r}", cur.lineno(pos))
        idx, vals = arr["index"].astype(np.int64), arr["values"].reshape(nitems, ncomp)
    else:
        vals = _numbers(cur.take(nitems * (ncomp + 1)), nitems * (ncomp + 1), np.float64,
                        f"$ElementData {name!r}", cur.lineno(pos)).reshape(nitems, ncomp + 1)
        idx, vals = vals[:, 0].astype(np.int64), vals[:, 1:]
    s, line = cur.next_line()
    if s != "$EndElementData":
        raise _ParseError(f"expected '$EndElementData' (line {line}), found {s!r}")
    return name, idx, vals, cur.pos


_TOLERANT = {"medit": _read_medit_text, "vtk": _read_legacy_vtk, "gmsh": _read_gmsh22_data}


# ---------------------------------------------------------------------------------------------------- writing
def _write_format(path: Path, file_format) -> str:
    writable = _writer_formats()
    if file_format is not None:
        fmt = _WRITE_ALIASES.get(str(file_format).lower(), str(file_format).lower())
        if fmt in _NO_WRITE:
            raise MeshWriteError(f"{path}: cannot write {fmt}: {_NO_WRITE[fmt]}")
        if fmt not in writable:
            raise MeshWriteError(f"{path}: expected a meshio writer name, found file_format={file_format!r}; "
                                 f"known: {', '.join(sorted(writable))}")
        return fmt
    ext, fmts = _ext_formats(path)
    fmt = _WRITE_BY_EXT.get(ext, fmts[0] if fmts else None)
    if fmt in _NO_WRITE:
        raise MeshWriteError(f"{path}: cannot write {fmt}: {_NO_WRITE[fmt]}")
    if fmt is None or fmt not in writable:
        shown = f"extension '{ext}'" if ext else "no extension"
        raise MeshWriteError(f"{path}: cannot tell the mesh format to write from {shown}; expected one of "
                             f"{_few_exts(write=True)}, or pass file_format=")
    return fmt


def write(mesh, path, *, file_format=None) -> list:
    """Write a mesh atomically; return warnings (strings) about what the format could not hold.

    Parameters
    ----------
    mesh : meshio.Mesh or HexMesh
        A HexMesh is written as ``mesh.to_meshio()``. The object is never modified.
    path : str or PathLike
        The target; its extension picks the format unless ``file_format`` is given.
    file_format : str, optional
        A meshio writer name; ``"gmsh"``/``"gmsh22"`` mean MSH 2.2 binary and ``"vtk"``/``"vtk42"``
        legacy VTK 4.2 ASCII (see the module docstring for why).

    Returns
    -------
    list of str
        One sentence per thing that was converted or dropped (empty when the file holds everything).

    Raises
    ------
    MeshWriteError
        unknown extension/format, missing directory, or the writer failed (no partial file is left).
    InvalidInputError
        ``mesh`` is not a meshio.Mesh / HexMesh.
    """
    if isinstance(mesh, HexMesh):
        mesh = mesh.to_meshio()
    if not isinstance(mesh, meshio.Mesh):
        raise InvalidInputError(f"expected a meshio.Mesh or HexMesh to write, found {type(mesh).__name__}")
    try:
        p = Path(os.fspath(path))
    except TypeError as exc:
        raise MeshWriteError(f"expected a file path, found {type(path).__name__}") from exc
    if p.is_dir():
        raise MeshWriteError(f"{p}: is a directory, expected a file path to write")
    fmt = _write_format(p, file_format)
    directory = p.parent if str(p.parent) else Path(".")
    if not directory.is_dir():
        raise MeshWriteError(f"{p}: cannot write, the directory {directory} does not exist")

    notes: list = []
    try:
        out, kwargs, post = _prepare(mesh, fmt, notes)
    except HexsosError:
        raise
    except Exception as exc:
        raise MeshWriteError(f"{p}: cannot prepare the mesh for {_name(fmt)}: {exc}") from exc
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=p.suffix or ".tmp", dir=str(directory))
        os.close(fd)
    except OSError as exc:
        raise MeshWriteError(f"{p}: cannot create a file in {directory} ({exc.strerror or exc})") from exc
    log: list = []
    try:
        with _quiet() as log:
            meshio.write(tmp, out, file_format=fmt, **kwargs)
        for fix in post:
            fix(tmp)
        os.chmod(tmp, _new_file_mode(p))
        os.replace(tmp, p)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        if isinstance(exc, HexsosError):
            raise
        if isinstance(exc, (Exception, SystemExit)):
            said = "; ".join(m for m in log if not m.startswith("Info"))
            reason = str(exc) or said or type(exc).__name__
            raise MeshWriteError(f"{p}: writing {_name(fmt)} failed: {_short(reason)}") from exc
        raise
    for m in log:
        if any(s in m for s in _NOISE):
            continue
        notes.append("meshio: " + m.split(":", 1)[-1].strip())
    return notes


_NOISE = ("only meant for debugging", "Appending zeros to replace the missing")


def _new_file_mode(p: Path) -> int:
    try:
        return p.stat().st_mode & 0o7777
    except OSError:
        mask = os.umask(0)
        os.umask(mask)
        return 0o666 & ~mask


def _prepare(mesh: meshio.Mesh, fmt: str, notes: list):
    """A private copy of mesh, ready for meshio's writer of fmt; returns (mesh, writer kwargs, post-fixes)."""
    voxels = [b for b in mesh.cells if b.type == "voxel"]
    cells = []
    for b in mesh.cells:
        if b.type == "voxel":
            cells.append(_copy_block(b, np.asarray(b.data)[:, VOXEL_TO_VTK], cell_type="hexahedron"))
        else:
            cells.append(_copy_block(b))
    m = _copy_mesh(mesh, cells=cells)
    if voxels:
        notes.append(f"{len(voxels)} voxel block(s) written as hexahedron blocks (VTK node order): "
                     "meshio has no voxel cell type")
    # Gmsh 4 entity topology (meshio's msh4 reader): meaningless outside MSH 4, which is not written here
    m.cell_sets.pop("gmsh:bounding_entities", None)
    if m.points.dtype.kind != "f" or m.points.dtype.itemsize < 4:
        m.points = m.points.astype(np.float64)
    _sanitize_dtypes(m, notes)
    kwargs, post = {}, []
    if fmt == "gmsh22":
        _prepare_gmsh22(m, notes)
        kwargs["binary"] = True
    elif fmt == "vtk42":
        _prepare_vtk42(m, notes, post)
        kwargs["binary"] = False
    elif fmt == "vtu":
        if m.field_data:
            fd = _numeric_field_data(m, notes, "VTU")
            m.field_data = {}
            if fd:
                post.append(lambda tmp, fd=fd: _inject_vtu_field_data(tmp, fd, notes))
    elif fmt == "medit":
        _prepare_medit(m, notes)
    return m, kwargs, post


def _sanitize_dtypes(m: meshio.Mesh, notes: list) -> None:
    as_int8, dropped = [], []
    for where, store in (("point", m.point_data), ("cell", m.cell_data)):
        for name in list(store):
            arrays = store[name] if where == "cell" else [store[name]]
            kinds = {np.asarray(a).dtype.kind for a in arrays}
            if kinds <= set("iuf") and not any(np.asarray(a).dtype == np.float16 for a in arrays):
                continue
            if kinds - set("biuf"):
                dropped.append(f"{name} ({where} data, dtype {np.asarray(arrays[0]).dtype})")
                del store[name]
                continue
            fixed = []
            for a in arrays:
                a = np.asarray(a)
                fixed.append(a.astype(np.int8) if a.dtype.kind == "b" else
                             a.astype(np.float32) if a.dtype == np.float16 else a)
            if "b" in kinds:
                as_int8.append(name)
            store[name] = fixed if where == "cell" else fixed[0]
    if as_int8:
        notes.append(f"boolean arrays written as int8: {', '.join(as_int8)}")
    if dropped:
        notes.append(f"arrays that no mesh format can hold were dropped: {', '.join(dropped)}")


def _components(arr: np.ndarray) -> np.ndarray:
    return arr.reshape(len(arr), -1) if arr.ndim > 2 else arr


def _prepare_gmsh22(m: meshio.Mesh, notes: list) -> None:
    if m.points.dtype != np.float64:
        m.points = m.points.astype(np.float64)
    for tag in ("gmsh:physical", "gmsh:geometrical"):
        if tag not in m.cell_data:
            m.cell_data[tag] = [np.zeros(len(b.data), dtype=np.int32) for b in m.cells]
            continue
        fixed = []
        for a in m.cell_data[tag]:
            a = np.asarray(a)
            a = a.reshape(len(a), -1)[:, 0] if a.ndim > 1 else a
            if a.dtype.kind == "f" and not (np.isfinite(a).all() and (a == np.round(a)).all()):
                fixed = None
                break
            fixed.append(a.astype(np.int32))
        if fixed is None:
            notes.append(f"cell data {tag} holds non-integer values; written as zeros (MSH element tags are int)")
            fixed = [np.zeros(len(b.data), dtype=np.int32) for b in m.cells]
        m.cell_data[tag] = fixed
    if "gmsh:dim_tags" in m.point_data:
        del m.point_data["gmsh:dim_tags"]
        notes.append("point data gmsh:dim_tags (Gmsh 4 node entities) is not stored in MSH 2.2: dropped")
    for store, where in ((m.point_data, "point"), (m.cell_data, "cell")):
        for name in list(store):
            if name in ("gmsh:physical", "gmsh:geometrical", "cell_tags"):
                continue
            arrays = store[name] if where == "cell" else [store[name]]
            arrays = [_components(np.asarray(a)) for a in arrays]
            k = 1 if arrays[0].ndim == 1 else arrays[0].shape[1]
            if k in (1, 3, 9):
                store[name] = arrays if where == "cell" else arrays[0]
            elif k < 9:
                width = 3 if k < 3 else 9
                padded = [np.concatenate([a.astype(np.float64), np.zeros((len(a), width - k))], axis=1) for a in arrays]
                store[name] = padded if where == "cell" else padded[0]
                notes.append(f"{where} data {name} has {k} components; MSH allows 1, 3 or 9: "
                             f"padded with zeros to {width}")
            else:
                del store[name]
                for c in range(k):
                    cols = [a[:, c] for a in arrays]
                    store[f"{name}_{c}"] = cols if where == "cell" else cols[0]
                notes.append(f"{where} data {name} has {k} components; MSH allows 1, 3 or 9: written as "
                             f"{name}_0 .. {name}_{k - 1}")
    keep, dropped = {}, []
    for name, value in m.field_data.items():
        try:
            arr = np.asarray(value).ravel()
            if arr.size == 2 and np.all(arr == np.round(arr)):
                keep[name] = arr.astype(np.int64)
                continue
        except (TypeError, ValueError):
            pass
        dropped.append(name)
    m.field_data = keep
    if dropped:
        notes.append("field data that is not a [tag, dim] pair (MSH $PhysicalNames) was dropped: " + ", ".join(dropped))
    # meshio reads Gmsh physical groups as cell sets too; in MSH 2.2 they live on as gmsh:physical + $PhysicalNames
    _drop_sets(m, notes, "MSH 2.2", quiet=set(keep))


def _drop_sets(m: meshio.Mesh, notes: list, fmt: str, quiet=()) -> None:
    names = [n for n in list(m.point_sets) + list(m.cell_sets) if n not in quiet]
    m.point_sets, m.cell_sets = {}, {}
    if names:
        notes.append(f"point/cell sets are not stored in {fmt}: dropped {', '.join(names)}")


def _numeric_field_data(m: meshio.Mesh, notes: list, fmt: str, *, no_spaces: bool = False) -> dict:
    keep, dropped = {}, []
    for name, value in m.field_data.items():
        try:
            arr = np.asarray(value)
        except Exception:
            arr = None
        if arr is None or arr.dtype.kind not in "biuf":
            dropped.append(str(name))
            continue
        arr = arr.reshape(1) if arr.ndim == 0 else arr
        arr = arr.reshape(len(arr), -1) if arr.ndim > 2 else arr
        key = str(name)
        if no_spaces and re.search(r"\s", key):
            key = re.sub(r"\s+", "_", key)
            notes.append(f"legacy VTK array names cannot hold spaces: field data {name!r} written as {key!r}")
        keep[key] = arr.astype(np.int8) if arr.dtype.kind == "b" else arr
    if dropped:
        notes.append(f"non-numeric field data cannot be stored in {fmt}: dropped {', '.join(dropped)}")
    return keep


def _prepare_vtk42(m: meshio.Mesh, notes: list, post: list) -> None:
    renamed = []
    for store, where in ((m.point_data, "point"), (m.cell_data, "cell")):
        for name in list(store):
            arrays = store[name] if where == "cell" else [store[name]]
            arrays = [_components(np.asarray(a)) for a in arrays]
            if arrays[0].ndim == 2 and arrays[0].shape[1] == 2:
                arrays = [np.concatenate([a, np.zeros((len(a), 1), dtype=a.dtype)], axis=1) for a in arrays]
                notes.append(f"{where} data {name} has 2 components; legacy VTK vectors have 3: padded with zeros")
            value = arrays if where == "cell" else arrays[0]
            new = re.sub(r"\s+", "_", str(name))
            del store[name]
            if new != name:
                renamed.append(f"{name!r} -> {new!r}")
            store[new] = value
    if renamed:
        notes.append("legacy VTK array names cannot hold spaces: renamed " + ", ".join(renamed))
    if m.field_data:
        fd = _numeric_field_data(m, notes, "legacy VTK", no_spaces=True)
        m.field_data = {}
        if fd:
            n_cells = sum(len(b.data) for b in m.cells)
            post.append(lambda tmp, fd=fd: _inject_vtk_field_data(tmp, fd, n_cells))
    _drop_sets(m, notes, "legacy VTK")


_VTK_NAMES = {"i1": "char", "u1": "unsigned_char", "i2": "short", "u2": "unsigned_short", "i4": "int",
              "u4": "unsigned_int", "i8": "long", "u8": "unsigned_long", "f4": "float", "f8": "double"}
_VTU_NAMES = {"i1": "Int8", "u1": "UInt8", "i2": "Int16", "u2": "UInt16", "i4": "Int32", "u4": "UInt32",
              "i8": "Int64", "u8": "UInt64", "f4": "Float32", "f8": "Float64"}


def _text_values(arr: np.ndarray) -> str:
    return " ".join(repr(x) if isinstance(x, float) else str(x) for x in arr.ravel().tolist())


def _inject_vtk_field_data(tmp: str, fd: dict, n_cells: int) -> None:
    """Add 'FIELD FieldData k' after CELL_TYPES (dataset-level field data; Gmsh stops reading before it)."""
    with open(tmp, "rb") as f:
        data = f.read()
    at = data.find(b"\nCELL_TYPES ")
    if at < 0:
        raise MeshWriteError("meshio's legacy VTK output has no CELL_TYPES section to put the field data after")
    pos = data.find(b"\n", at + 1) + 1
    cur = _Cursor(data)
    cur.pos = pos
    cur.take(n_cells)
    pos = cur.pos
    if n_cells and data[pos - 1:pos] != b"\n":
        nl = data.find(b"\n", pos)
        pos = len(data) if nl < 0 else nl + 1
    lines = [f"FIELD FieldData {len(fd)}"]
    for name, arr in fd.items():
        ncomp = 1 if arr.ndim == 1 else arr.shape[1]
        lines.append(f"{name} {ncomp} {len(arr)} {_VTK_NAMES[arr.dtype.str[1:]]}")
        lines.append(_text_values(arr))
    block = ("\n".join(lines) + "\n").encode()
    with open(tmp, "wb") as f:
        f.write(data[:pos] + block + data[pos:])


def _inject_vtu_field_data(tmp: str, fd: dict, notes: list) -> None:
    """Add a <FieldData> element (ASCII DataArrays) as the first child of <UnstructuredGrid>."""
    with open(tmp, "rb") as f:
        data = f.read()
    tag = b"<UnstructuredGrid>"
    at = data.find(tag)
    if at < 0:
        notes.append("field data could not be added to the VTU file (no <UnstructuredGrid> element): dropped "
                     + ", ".join(fd))
        return
    parts = ["<FieldData>"]
    for name, arr in fd.items():
        ncomp = "" if arr.ndim == 1 else f' NumberOfComponents="{arr.shape[1]}"'
        safe = name.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;")
        parts.append(f'<DataArray type="{_VTU_NAMES[arr.dtype.str[1:]]}" Name="{safe}" '
                     f'NumberOfTuples="{len(arr)}"{ncomp} format="ascii">{_text_values(arr)}</DataArray>')
    parts.append("</FieldData>")
    with open(tmp, "wb") as f:
        f.write(data[: at + len(tag)] + "".join(parts).encode() + data[at + len(tag):])


_MEDIT_TYPES = {"line", "triangle", "quad", "tetra", "wedge", "pyramid", "hexahedron"}


def _prepare_medit(m: meshio.Mesh, notes: list) -> None:
    if m.points.dtype not in (np.float32, np.float64):
        m.points = m.points.astype(np.float64)
    skip = [b for b, blk in enumerate(m.cells) if blk.type not in _MEDIT_TYPES]
    if skip:
        desc = ", ".join(f"{len(m.cells[b].data)} {m.cells[b].type}" for b in skip)
        notes.append(f"Medit cannot hold {desc} cells: skipped")
        keep = [b for b in range(len(m.cells)) if b not in skip]
        m.cells = [m.cells[b] for b in keep]
        m.cell_data = {k: [v[b] for b in keep] for k, v in m.cell_data.items()}

    def pick(store, candidates, per_block):
        for name in candidates:
            if name in store:
                arrays = store[name] if per_block else [store[name]]
                arrays = [np.asarray(a) for a in arrays]
                if all(a.ndim == 1 and (a.dtype.kind in "iu" or (a.dtype.kind == "f" and np.isfinite(a).all()
                                                                 and (a == np.round(a)).all())) for a in arrays):
                    return name, [a.astype(np.int64) for a in arrays]
        return None, None

    cname, cref = pick(m.cell_data, ("medit:ref", "gmsh:physical"), True)
    dropped_c = [n for n in m.cell_data if n != cname]
    m.cell_data = {"medit:ref": cref} if cname else {}
    pname, pref = pick(m.point_data, ("medit:ref",), False)
    dropped_p = [n for n in m.point_data if n != pname]
    m.point_data = {"medit:ref": pref[0]} if pname else {}
    if dropped_c:
        kept = f" (kept {cname!r} as the element reference)" if cname else ""
        notes.append(f"Medit .mesh cannot hold cell data: dropped {', '.join(dropped_c)}{kept}")
    if dropped_p:
        notes.append(f"Medit .mesh cannot hold point data: dropped {', '.join(dropped_p)}")
    if m.field_data:
        notes.append(f"Medit .mesh cannot hold field data: dropped {', '.join(map(str, m.field_data))}")
        m.field_data = {}
    _drop_sets(m, notes, "Medit")
