"""Reading a large mesh: every reader hexsos can use for a format, side by side, in one process.

    python -m comparison.bench_read [--n 97] [--repeat 3] [--rss]

Builds the twisted n^3 grid of :mod:`comparison.bench_scale` (97^3 = 912,673 hexes), writes it as Gmsh writes it
(binary MSH 4.1 and 2.2), as hexsos writes it (``.msh`` MSH 2.2 binary, ``.vtu``, ``.vtk`` ASCII) and as binary
legacy VTK, then times each reader that can read each file (best of ``--repeat``) and prints its time and its
ratio to meshio's. With ``--rss`` each reader also runs alone in a fresh process under ``/usr/bin/time -v``
(peak resident memory of the whole process, imports included). Also printed: the cost of importing VTK's
readers, which a ``.vtu`` read pays once per process.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import io  # noqa: E402
import re  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402


def write_files(P, H, d):
    """{label: (path, hexsos format name)}."""
    import gmsh
    import meshio

    from hexsos_plugins.io import write

    files = {}
    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("big")
        tag = gmsh.model.addDiscreteEntity(3)
        gmsh.model.mesh.addNodes(3, tag, np.arange(1, len(P) + 1), P.ravel())
        gmsh.model.mesh.addElementsByType(tag, 5, np.arange(1, len(H) + 1), (H + 1).ravel())
        gmsh.model.addPhysicalGroup(3, [tag], 1, "Body")
        gmsh.option.setNumber("Mesh.Binary", 1)
        for v in (4.1, 2.2):
            gmsh.option.setNumber("Mesh.MshFileVersion", v)
            files[f"Gmsh MSH {v} binary"] = (os.path.join(d, f"gmsh{v}.msh"), "gmsh")
            gmsh.write(files[f"Gmsh MSH {v} binary"][0])
    finally:
        gmsh.finalize()
    m = meshio.Mesh(P, [("hexahedron", H)])
    for label, name, fmt in (("hexsos .msh (2.2 binary)", "ours.msh", "gmsh"), ("hexsos .vtu", "ours.vtu", "vtu"),
                             ("hexsos .vtk (ASCII)", "ours.vtk", "vtk")):
        files[label] = (os.path.join(d, name), fmt)
        write(m, files[label][0])
    files["legacy VTK binary"] = (os.path.join(d, "binary.vtk"), "vtk")
    with contextlib.redirect_stdout(io.StringIO()):
        meshio.write(files["legacy VTK binary"][0], m, file_format="vtk42", binary=True)
    return files


def _plain_meshio(path):
    import meshio

    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return meshio.read(path)


def time_readers(path, fmt, repeat):
    from hexsos_plugins.io.readers import readers_for

    rows = [("meshio (plain)", _plain_meshio)]
    rows += [(who, fn) for who, fn in readers_for(path, fmt) if who != "meshio"]
    out = []
    for who, fn in rows:
        best = None
        try:
            for _ in range(repeat):
                t = time.perf_counter()
                fn(Path(path))
                best = min(best or 1e300, time.perf_counter() - t)
        except Exception as exc:  # noqa: BLE001 - a reader that cannot read this file
            out.append((who, None, f"{type(exc).__name__}: {str(exc)[:60]}"))
            continue
        out.append((who, best, ""))
    return out


_CHILD = """
import sys, time
from pathlib import Path
who, path, fmt = sys.argv[1], sys.argv[2], sys.argv[3]
t = time.perf_counter()
if who == "meshio (plain)":
    import meshio; meshio.read(path)
else:
    from hexsos_plugins.io.readers import readers_for
    dict(readers_for(path, fmt))[who](Path(path))
print(time.perf_counter() - t)
"""


def rss(who, path, fmt):
    cmd = ["/usr/bin/time", "-v", sys.executable, "-c", _CHILD, who, path, fmt]
    out = subprocess.run(cmd, capture_output=True, text=True, check=False)
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", out.stderr)
    return int(m.group(1)) / 1024 if m else float("nan")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=97, help="grid size n (n^3 hexes; default 97: 912,673)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--rss", action="store_true", help="also the peak RSS of each reader alone in a process")
    args = ap.parse_args(argv)
    from comparison.bench_scale import big_mesh

    P, H = big_mesh(args.n)
    print(f"mesh: {len(H):,} hexes, {len(P):,} points")
    for mod in ("vtkmodules.vtkIOXML", "gmsh", "meshio"):
        ts = []
        for _ in range(3):
            t = time.perf_counter()
            subprocess.run([sys.executable, "-c", f"import {mod}"], check=True)
            ts.append(time.perf_counter() - t)
        t = time.perf_counter()
        subprocess.run([sys.executable, "-c", "pass"], check=True)
        t0 = time.perf_counter() - t
        print(f"python -c 'import {mod}': {min(ts):.2f} s (python -c pass: {t0:.2f} s)")
    with tempfile.TemporaryDirectory() as d:
        files = write_files(P, H, d)
        for label, (path, fmt) in files.items():
            size = os.path.getsize(path) / 2**20
            print(f"\n{label} ({size:.0f} MB)")
            rows = time_readers(path, fmt, args.repeat)
            ref = rows[0][1]
            for who, sec, note in rows:
                if sec is None:
                    print(f"  {who:16s}      -    {note}")
                    continue
                ratio = f"{ref / sec:6.2f}x meshio's speed" if ref else ""
                mem = f"  peak RSS {rss(who, path, fmt):5.0f} MB" if args.rss else ""
                print(f"  {who:16s} {sec:6.2f} s  {ratio}{mem}")


if __name__ == "__main__":
    main()
