"""What hexsos does with bad or unusual input: the cases, the outcomes, and the README table.

    python -m comparison.robustness        # prints the Markdown table of the README

Every case writes its own file (nothing third-party), runs ``hexsos check`` in process and records the exit
code and the line on stderr (or the verdict counts). ``tests/test_robustness.py`` asserts every expected
outcome below, so the table is what the tests check.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
import time

import meshio
import numpy as np

from hexsos_plugins.examples import hexes_to_mesh, random_hexes, structured_grid, unit_cube

__all__ = ["CASES", "run_case", "table", "fuzz"]


def _write(path, points, cells, **kw):
    from hexsos_plugins.io import write

    write(meshio.Mesh(np.asarray(points, float), cells, **kw), path)


def _grid(path, n=2, scale=1.0):
    P, H = structured_grid(n)
    _write(path, P * scale, [("hexahedron", H)])


def _missing(d):
    return os.path.join(d, "missing.vtu"), []


def _empty(d):
    p = os.path.join(d, "empty.vtk")
    open(p, "wb").close()
    return p, []


def _garbage(d):
    p = os.path.join(d, "garbage.vtk")
    with open(p, "wb") as f:
        f.write(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    return p, []


def _truncated(d):
    full = os.path.join(d, "full.vtk")
    _grid(full, 3)
    with open(full, "rb") as f:
        data = f.read()
    p = os.path.join(d, "truncated.vtk")
    with open(p, "wb") as f:
        f.write(data[: len(data) // 2])
    return p, []


def _unknown_ext(d):
    p = os.path.join(d, "mesh.xyz")
    with open(p, "w") as f:
        f.write("1 2 3\n")
    return p, []


def _nan(d, value=np.nan):
    P, H = structured_grid(2)
    P[5] = value
    p = os.path.join(d, "nan.vtu" if np.isnan(value) else "inf.vtu")
    meshio.write(p, meshio.Mesh(P, [("hexahedron", H)]))
    return p, []


def _inf(d):
    return _nan(d, np.inf)


def _out_of_range(d):
    p = os.path.join(d, "range.vtk")
    with open(p, "w") as f:
        f.write("# vtk DataFile Version 4.2\nbad index\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS 8 double\n")
        for c in unit_cube():
            f.write(" ".join(map(str, c)) + "\n")
        f.write("CELLS 1 9\n8 0 1 2 3 4 5 6 11\nCELL_TYPES 1\n12\n")
    return p, []


def _tets_only(d):
    # two tets sharing a face, and an inverted one on points of its own
    p = os.path.join(d, "tets.vtu")
    _write(p, np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1], [3, 0, 0], [4, 0, 0], [3, 1, 0],
                        [3, 0, 1]]),
           [("tetra", np.array([[0, 1, 2, 3], [1, 2, 3, 4], [5, 7, 6, 8]]))])
    return p, []


def _repeated_mirrored(d):
    # a tet and its copy in the mirrored node order: the copy is written in the other handedness
    p = os.path.join(d, "repeated-mirrored.vtu")
    _write(p, np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]]),
           [("tetra", np.array([[0, 1, 2, 3], [1, 2, 3, 4], [1, 3, 2, 4]]))])
    return p, []


def _quads_only(d):
    p = os.path.join(d, "quads.vtu")
    _write(p, unit_cube()[:4], [("quad", np.array([[0, 1, 2, 3]]))])
    return p, []


def _repeated_vertex(d):
    X = unit_cube()
    X[1] = X[0]
    p = os.path.join(d, "collapsed.vtu")
    _write(p, X, [("hexahedron", np.array([[0, 1, 2, 3, 4, 5, 6, 7]]))])
    return p, []


def _repeated_index(d):
    p = os.path.join(d, "repeated-index.vtu")
    _write(p, unit_cube(), [("hexahedron", np.array([[0, 0, 2, 3, 4, 5, 6, 7]]))])
    return p, []


def _flat(d):
    X = unit_cube() * [1, 1, 0]
    p = os.path.join(d, "flat.vtu")
    _write(p, X, [("hexahedron", np.arange(8)[None])])
    return p, []


def _left_handed(d, fix=False):
    P, H = structured_grid(2)
    p = os.path.join(d, "left.vtu")
    _write(p, P, [("hexahedron", H[:, [0, 3, 2, 1, 4, 7, 6, 5]])])
    return p, (["--fix-orientation"] if fix else [])


def _left_handed_fixed(d):
    return _left_handed(d, True)


def _mirrored_block(d, fix=False):
    P, H = structured_grid(2)
    H = H.copy()
    half = P[H[:, 0], 0] == P[:, 0].min()  # the 4 hexes of the lower half in x, written mirrored
    H[half] = H[half][:, [0, 3, 2, 1, 4, 7, 6, 5]]
    p = os.path.join(d, "mirrored-block.vtu")
    _write(p, P, [("hexahedron", H)])
    return p, (["--fix-orientation"] if fix else [])


def _mirrored_block_fixed(d):
    return _mirrored_block(d, True)


def _voxels(d):
    P, H = structured_grid(2)
    voxel = H[:, [0, 1, 3, 2, 4, 5, 7, 6]]  # VTK_VOXEL order: x fastest
    p = os.path.join(d, "voxels.vtk")
    with open(p, "w") as f:
        f.write(f"# vtk DataFile Version 4.2\nvoxels\nASCII\nDATASET UNSTRUCTURED_GRID\nPOINTS {len(P)} double\n")
        f.writelines(" ".join(map(str, c)) + "\n" for c in P)
        f.write(f"CELLS {len(voxel)} {9 * len(voxel)}\n")
        f.writelines("8 " + " ".join(map(str, v)) + "\n" for v in voxel)
        f.write(f"CELL_TYPES {len(voxel)}\n" + "11\n" * len(voxel))
    return p, []


def _mixed(d):
    """8 hexes, a tet and a pyramid on their top face, and quads (2-D cells are not checked)."""
    P, H = structured_grid(2)
    top = P[:, 2].max()
    extra = np.array([[0.0, 0.0, top + 1.0], [0.5, 0.5, top + 1.0], [1.0, 1.0, top + 0.5]])
    P = np.vstack([P, extra])
    n = len(P) - 3

    def at(x, y, z):
        return int(np.flatnonzero(np.all(np.isclose(P, [x, y, z]), axis=1))[0])

    pyramid = [[at(0.5, 0.5, top), at(1, 0.5, top), at(1, 1, top), at(0.5, 1, top), n + 2]]
    tets = [[at(0, 0, top), at(0.5, 0, top), at(0, 0.5, top), n]]
    _write(p := os.path.join(d, "mixed.vtu"), P, [("hexahedron", H), ("tetra", np.array(tets)),
                                                   ("pyramid", np.array(pyramid)), ("quad", H[:3, :4])])
    return p, []


def _unreferenced(d):
    P, H = structured_grid(2)
    P = np.vstack([P, [[9.0, 9.0, 9.0], [-5.0, 0.0, 1e30]]])
    p = os.path.join(d, "unreferenced.vtu")
    _write(p, P, [("hexahedron", H)])
    return p, []


def _duplicates(d):
    # every hex has its own 8 points: coinciding points, no sharing
    P, H = hexes_to_mesh(structured_grid(2)[0][structured_grid(2)[1]])
    p = os.path.join(d, "duplicates.vtu")
    _write(p, P, [("hexahedron", H)])
    return p, []


def _repeated(d):
    # a hex written again in a second block of hexahedra (as in two physical groups), its nodes turned
    P, H = structured_grid(2)
    p = os.path.join(d, "repeated.vtu")
    _write(p, P, [("hexahedron", H), ("hexahedron", H[3:4][:, [1, 2, 3, 0, 5, 6, 7, 4]])])
    return p, []


def _scaled(scale):
    def make(d):
        P, H = hexes_to_mesh(random_hexes(200, sigma=0.3, seed=7))
        p = os.path.join(d, f"scaled-{scale:g}.vtu")
        _write(p, P * scale + 3.0 * scale, [("hexahedron", H)])
        return p, ["--json"]

    return make


#: (case, what it is, file maker, expected exit code, text expected on stderr, or counts expected)
CASES = [
    ("missing file", "a path that does not exist", _missing, 2, "no such file", None),
    ("empty file", "0 bytes, .vtk", _empty, 2, "empty", None),
    ("binary garbage", "4 kB of random bytes named .vtk", _garbage, 2, "could not read", None),
    ("truncated file", "a legacy VTK file cut in half", _truncated, 2, "truncated", None),
    ("unknown extension", "mesh.xyz", _unknown_ext, 2, "cannot tell the mesh format", None),
    ("NaN coordinates", "a referenced point at NaN", _nan, 2, "expected finite point coordinates", None),
    ("infinite coordinates", "a referenced point at inf", _inf, 2, "expected finite point coordinates", None),
    ("cell index out of range", "a hex naming node 11 of 8", _out_of_range, 2, "references point 11", None),
    ("tets only", "a mesh of tetrahedra, one of them inverted", _tets_only, 1, None,
     {"cells": 3, "hexes": 0, "valid": 2, "invalid": 1}),
    ("quads only", "no 3-D cells", _quads_only, 2, "expected 3-D cells hexsos can check", None),
    ("repeated vertex (coordinates)", "two nodes of a hex at one point: a collapsed edge", _repeated_vertex, 1,
     None, {"invalid": 1}),
    ("repeated vertex (index)", "a hex naming one node twice", _repeated_index, 1, None, {"invalid": 1}),
    ("flat hex", "all 8 nodes in a plane: det J = 0 everywhere", _flat, 1, None, {"undecided": 1, "flat": 1}),
    ("left-handed file", "every hex in the mirrored node order", _left_handed, 2, "left-handed", None),
    ("left-handed, --fix-orientation", "the same, flipped on request", _left_handed_fixed, 0, None, {"valid": 8}),
    ("mirrored block", "4 of 8 hexes in the mirrored node order", _mirrored_block, 2, "partly mirrored", None),
    ("mirrored block, --fix-orientation", "the same, flipped on request", _mirrored_block_fixed, 0, None,
     {"valid": 8}),
    ("VTK voxels", "cell type 11 (x-fastest node order)", _voxels, 0, None, {"valid": 8}),
    ("mixed mesh", "hexes with a tet, a pyramid and quads", _mixed, 0, None, {"cells": 10, "hexes": 8, "valid": 10}),
    ("unreferenced points", "points no cell uses (one at 1e30)", _unreferenced, 0, None, {"valid": 8}),
    ("duplicate points", "coinciding points, no node shared", _duplicates, 0, None, {"valid": 8}),
    ("repeated cell", "a hex written again in a second block, its nodes turned", _repeated, 0, None,
     {"valid": 9, "repeated_cells": 1}),
    ("repeated cell, mirrored", "a tet and its copy in the mirrored node order", _repeated_mirrored, 2,
     "partly mirrored", None),
] + [(f"scale {s:g}", "200 random hexes (sigma 0.3), coordinates times this", _scaled(s), 1, None, "same verdicts")
     for s in (1e-6, 1e-3, 1.0, 1e3, 1e6)]


def run_case(case, directory):
    """Run ``hexsos check`` on the case's file; return (exit code, stderr line, stdout)."""
    from hexsos_plugins import cli

    name, _, make, _, _, _ = case
    path, extra = make(directory)
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli.main(["check", path, "--json"] + [e for e in extra if e != "--json"])
    return code, err.getvalue().strip(), out.getvalue().strip()


def _outcome(code, err, out):
    if err:
        return f"exit {code}: `{err.replace('hexsos: error: ', '')[:110]}`"
    d = json.loads(out)
    parts = [f"{d[k]} {k}" for k in ("valid", "invalid", "undecided") if d[k]]
    if d.get("flat"):
        parts.append(f"({d['flat']} flat)")
    if d.get("repeated_cells"):
        parts.append(f"({d['repeated_cells']} named twice)")
    return f"exit {code}: " + ", ".join(parts)


def table() -> str:
    rows = ["| input | what | outcome |", "|---|---|---|"]
    with tempfile.TemporaryDirectory() as d:
        for case in CASES:
            code, err, out = run_case(case, d)
            text = _outcome(code, err, out).replace(d + os.sep, "").replace("|", "\\|")
            rows.append(f"| {case[0]} | {case[1]} | {text} |")
    return "\n".join(rows)


def _seed_files(d):
    from hexsos_plugins.io import write

    P, H = structured_grid(2)
    m = meshio.Mesh(P, [("hexahedron", H), ("quad", H[:2, :4])], point_data={"t": np.arange(len(P), dtype=float)},
                    cell_data={"r": [np.arange(8.0), np.arange(2.0)]})
    paths = []
    for ext in (".vtk", ".vtu", ".msh", ".mesh"):
        p = os.path.join(d, f"seed{ext}")
        write(m, p)
        paths.append(p)
    # the tolerant variants too: 'Vertices N' on one line, 'Quads', 8-node cells typed 10, trailing text
    p = os.path.join(d, "variant.mesh")
    with open(p, "w") as f:
        f.write("MeshVersionFormatted 2\nDimension 3\nVertices 8\n")
        f.writelines(" ".join(map(str, c)) + " 0\n" for c in unit_cube())
        f.write("Quads 1\n1 2 3 4 0\nHexahedra 1\n1 2 3 4 5 6 7 8 0\nEnd\ntrailing text\n")
    paths.append(p)
    return paths


def mutate(data: bytes, rng) -> bytes:
    """A few random edits: byte flips, truncation, insertion, deletion, digit swaps."""
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 6))):
        kind = rng.integers(0, 5)
        i = int(rng.integers(0, max(len(b), 1)))
        if kind == 0 and b:
            b[i % len(b)] = int(rng.integers(0, 256))
        elif kind == 1:
            b = b[:i]
        elif kind == 2:
            b[i:i] = rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8).tobytes()
        elif kind == 3 and b:
            del b[i : int(rng.integers(i, len(b) + 1))]
        elif b:
            digits = b"0123456789-+.eE \n"
            b[i % len(b)] = digits[int(rng.integers(0, len(digits)))]
    return bytes(b)


def fuzz(seconds: float, directory: str, *, seed: int = 1234) -> dict:
    """Read and check mutated mesh files for ``seconds``; anything but success or a typed error is a crash."""
    import hexsos_plugins as hs

    rng = np.random.default_rng(seed)
    seeds = _seed_files(directory)
    deadline = time.monotonic() + seconds
    stats = {"files": 0, "read": 0, "typed_errors": 0, "crashes": []}
    while time.monotonic() < deadline:
        src = seeds[stats["files"] % len(seeds)]
        with open(src, "rb") as f:
            data = mutate(f.read(), rng)
        dst = os.path.join(directory, "fuzz" + os.path.splitext(src)[1])
        with open(dst, "wb") as f:
            f.write(data)
        try:
            mesh = hs.read(dst)
            hs.check(mesh.points, mesh.hexes)
            stats["read"] += 1
        except hs.HexsosError:
            stats["typed_errors"] += 1
        except BaseException as exc:  # noqa: BLE001 - that is what we are looking for
            if isinstance(exc, KeyboardInterrupt):
                raise
            keep = os.path.join(directory, f"crash-{len(stats['crashes'])}" + os.path.splitext(src)[1])
            with open(keep, "wb") as f:
                f.write(data)
            stats["crashes"].append(f"{type(exc).__name__}: {exc} ({keep})")
        stats["files"] += 1
    return stats


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description="the README's bad-input table, or --fuzz SECONDS of reader fuzzing")
    ap.add_argument("--fuzz", type=float, metavar="SECONDS", help="fuzz the readers for this long")
    ap.add_argument("--keep", metavar="DIR", help="where to keep crashing files (default: a temporary folder)")
    a = ap.parse_args()
    if a.fuzz:
        d = a.keep or tempfile.mkdtemp(prefix="hexsos-fuzz-")
        os.makedirs(d, exist_ok=True)
        print(json.dumps(fuzz(a.fuzz, d), indent=1))
    else:
        print(table())
