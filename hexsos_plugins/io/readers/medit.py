"""Medit ``.mesh`` (ASCII), tolerant of what meshio 5.3.5 rejects: counts on the keyword's line
(``Vertices 8``) or on the next line, the keyword ``Quads`` for ``Quadrilaterals``, ``#`` comments, text after
``End`` or after the last section. Medit's node orders are taken as meshio takes them."""

from __future__ import annotations

import meshio
import numpy as np

from .common import ParseError
from .tokens import Cursor, is_number, numbers

__all__ = ["read_medit_text", "medit_points_float64"]


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


def read_medit_text(raw: bytes, path) -> meshio.Mesh:
    """Medit ASCII, tolerant of 'Vertices 8' on one line, 'Quads', comments and trailing text."""
    if str(path).lower().endswith(".meshb"):
        raise ParseError("binary Medit (.meshb) is read by meshio only")
    cur = Cursor(raw, comment="#")
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
            if is_number(tok) and (points is not None or cells):
                raise ParseError(f"expected a Medit keyword, found the number {tok[:40]!r} (line {line}): "
                                  "does the count of the section before it match its data?")
            if points is not None and cells and not _medit_keyword_follows(cur):
                break  # text appended after the data
            if points is None and not cells:
                raise ParseError(f"expected a Medit keyword such as 'MeshVersionFormatted' or 'Vertices', "
                                  f"found {tok[:40]!r} (line {line})")
            raise ParseError(f"expected a Medit keyword, found {tok[:40]!r} (line {line})")
        if key in ("identifier", "geometry"):
            if cur.rest_of_line() == "":
                cur.rest_of_line()
            continue
        value, vat = cur.token()
        if key in ("meshversionformatted", "dimension"):
            if value is None or not value.lstrip("+-").isdigit():
                found = "the end of the file" if value is None else repr(value[:40])
                raise ParseError(f"expected an integer after '{tok}', found {found} (line {cur.lineno(vat)})")
            if key == "dimension":
                dim = int(value)
                if dim not in (2, 3):
                    raise ParseError(f"expected 'Dimension' 2 or 3, found {dim} (line {cur.lineno(vat)})")
            continue
        what = "vertex" if key == "vertices" else _MEDIT_CELLS[key][0] if key in _MEDIT_CELLS else "entry"
        if value is None or not value.lstrip("+").isdigit():
            found = "the end of the file" if value is None else repr(value[:40])
            article = "an" if what[0] in "aeiou" else "a"
            raise ParseError(f"expected {article} {what} count after '{tok}', found {found} "
                              f"(line {cur.lineno(vat) if value is not None else line})")
        count = int(value)
        if key == "vertices":
            vals = numbers(cur.take(count * (dim + 1)), count * (dim + 1), np.float64, f"'{tok} {count}'", line)
            vals = vals.reshape(count, dim + 1)
            points = vals[:, :dim]
            point_ref = vals[:, dim].astype(np.int64)
        elif key in _MEDIT_CELLS:
            ctype, k = _MEDIT_CELLS[key]
            vals = numbers(cur.take(count * (k + 1)), count * (k + 1), np.int64, f"'{tok} {count}'", line)
            vals = vals.reshape(count, k + 1)
            cells.append((ctype, vals[:, :k] - 1))
            refs.append(vals[:, k])
        else:
            per = dim if _MEDIT_SKIP[key] == "d" else _MEDIT_SKIP[key]
            numbers(cur.take(count * per), count * per, np.float64, f"'{tok} {count}'", line)
    if points is None:
        raise ParseError("expected a 'Vertices' section, found none")
    return meshio.Mesh(points, cells, point_data={"medit:ref": point_ref}, cell_data={"medit:ref": refs})


def _medit_keyword_follows(cur: Cursor) -> bool:
    rest = cur.text[cur.pos:]
    for line in rest.splitlines():
        words = line.split("#", 1)[0].split()
        if words and words[0].lower() in _MEDIT_KEYS - {"end"}:
            return True
    return False


read_medit_text = read_medit_text


def medit_points_float64(raw: bytes, n_points: int):
    """The 'Vertices' coordinates of an ASCII Medit file as float64 (N, dim), read from the text: meshio reads
    them in single precision when the file says ``MeshVersionFormatted 1``. None when the section cannot be
    found or holds another number of vertices than ``n_points``."""
    cur = Cursor(raw, comment="#")
    dim = 3
    while True:
        tok, at = cur.token()
        if tok is None:
            return None
        key = tok.lower()
        if key == "dimension":
            value, _ = cur.token()
            if value is None or not value.isdigit():
                return None
            dim = int(value)
        elif key == "vertices":
            value, _ = cur.token()
            if value is None or not value.isdigit() or int(value) != n_points:
                return None
            count = int(value)
            try:
                vals = numbers(cur.take(count * (dim + 1)), count * (dim + 1), np.float64, "'Vertices'",
                                cur.lineno(at))
            except ParseError:
                return None
            return vals.reshape(count, dim + 1)[:, :dim]
