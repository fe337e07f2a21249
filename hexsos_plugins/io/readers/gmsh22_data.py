"""Gmsh MSH 2.x with ``$ElementData`` on a mesh of several cell blocks, which meshio 5.3.5 splits wrongly and
fails on: the data sections are parsed here, the rest by meshio (whose node orders :func:`fix_read_order`
corrects). Assumes element tags 1..M in file order, as meshio and Gmsh write them."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

import meshio
import numpy as np

from .common import ParseError, meshio_read
from ..meshio_conventions import fix_read_order
from .tokens import Cursor, numbers

__all__ = ["read_gmsh22_data"]


def read_gmsh22_data(raw: bytes, path) -> meshio.Mesh:
    """MSH 2.x whose $ElementData meshio 5.3.5 splits wrongly over several blocks: parse the data here."""
    head = raw.lstrip()[:200].split(b"\n")
    if len(head) < 2 or head[0].strip() != b"$MeshFormat":
        raise ParseError("expected '$MeshFormat' at the start of the file")
    parts = head[1].split()
    if not parts or not parts[0].startswith(b"2"):
        raise ParseError(f"meshio could not read this MSH {parts[0].decode('latin-1') if parts else '?'} file")
    binary = len(parts) > 1 and parts[1] == b"1"
    start = raw.find(b"$EndElements")
    if start < 0 or raw.find(b"$ElementData", start) < 0:
        raise ParseError("meshio could not read this MSH 2 file (and it has no $ElementData to work around)")
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
        mesh, _ = meshio_read(Path(tmp), "gmsh")
        fix_read_order(mesh, "gmsh")
    finally:
        with contextlib.suppress(OSError):
            os.remove(tmp)
    lengths = [len(b.data) for b in mesh.cells]
    total = sum(lengths)
    for name, idx, vals in sections:
        if len(idx) != total or not np.array_equal(np.sort(idx), np.arange(1, total + 1)):
            raise ParseError(f"$ElementData {name!r} has {len(idx)} values for elements "
                              f"{int(idx.min()) if len(idx) else 0}..{int(idx.max()) if len(idx) else 0}, "
                              f"expected one per element 1..{total}")
        vals = vals[np.argsort(idx, kind="stable")]
        if vals.shape[1] == 1:
            vals = vals[:, 0]
        mesh.cell_data[name] = np.split(vals, np.cumsum(lengths)[:-1])
    return mesh


def _parse_gmsh_data(raw: bytes, pos: int, binary: bool):
    cur = Cursor(raw)
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
        raise ParseError(f"malformed $ElementData header (line {cur.lineno(pos)})") from None
    name = strings[0] if strings else f"data_{pos}"
    if binary:
        dt = np.dtype([("index", "=i4"), ("values", "=f8", (ncomp,))])
        arr = cur.binary(nitems, dt, f"$ElementData {name!r}", cur.lineno(pos))
        idx, vals = arr["index"].astype(np.int64), arr["values"].reshape(nitems, ncomp)
    else:
        vals = numbers(cur.take(nitems * (ncomp + 1)), nitems * (ncomp + 1), np.float64,
                        f"$ElementData {name!r}", cur.lineno(pos)).reshape(nitems, ncomp + 1)
        idx, vals = vals[:, 0].astype(np.int64), vals[:, 1:]
    s, line = cur.next_line()
    if s != "$EndElementData":
        raise ParseError(f"expected '$EndElementData' (line {line}), found {s!r}")
    return name, idx, vals, cur.pos


read_gmsh22_data = read_gmsh22_data
