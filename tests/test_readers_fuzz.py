"""Reader fuzzing, deterministic: a seeded number of mutated files per format (no wall-clock budget), every one
read or refused with a typed error, through every reader path (numpy MSH, Gmsh's and VTK's readers, meshio,
the tolerant readers)."""

from __future__ import annotations

import os

import meshio
import numpy as np
import pytest

import hexsos_plugins.io as hio
from comparison.robustness import mutate  # the one mutation helper, shared with the on-demand fuzzer
from hexsos_plugins.errors import HexsosError

#: mutated files per seed file, and the seed of the mutations
N_PER_SEED = 60
SEED = 20240611


def grid(n):
    x = np.arange(n + 1, dtype=float)
    Z, Y, X = np.meshgrid(x, x, x, indexing="ij")
    points = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])
    c = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)[:-1, :-1, :-1]
    s, t = n + 1, (n + 1) ** 2
    hexes = np.stack([c, c + 1, c + s + 1, c + s, c + t, c + t + 1, c + t + s + 1, c + t + s], -1).reshape(-1, 8)
    return points, hexes


def seed_files(d):
    P, H = grid(2)
    n = len(P)
    P = np.vstack([P, [[0, 0, 3.0], [1, 0, 3], [0, 1, 3], [0, 0, 4], [1, 0, 4], [0, 1, 4]]])
    m = meshio.Mesh(P, [("hexahedron", H), ("quad", H[:2, :4]), ("tetra", [[n, n + 1, n + 2, n + 3]]),
                        ("wedge", [[n, n + 1, n + 2, n + 3, n + 4, n + 5]])],
                    point_data={"t": np.arange(len(P), dtype=float)},
                    cell_data={"r": [np.arange(8.0), np.arange(2.0), np.arange(1.0), np.arange(1.0)]},
                    field_data={"Body": np.array([1, 3])})
    paths = []
    for ext in (".vtk", ".vtu", ".msh", ".mesh"):
        p = os.path.join(d, f"seed{ext}")
        hio.write(m, p)
        paths.append(p)
    p = os.path.join(d, "seed_binary.vtk")
    meshio.write(p, m, file_format="vtk42", binary=True)
    paths.append(p)
    gmsh = pytest.importorskip("gmsh")
    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        gmsh.model.occ.synchronize()
        gmsh.model.addPhysicalGroup(3, [1], 5, "Box")
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.6)
        gmsh.model.mesh.generate(3)
        for suffix, binary in (("41b", 1), ("41", 0)):
            gmsh.option.setNumber("Mesh.Binary", binary)
            p = os.path.join(d, f"gmsh_{suffix}.msh")
            gmsh.write(p)
            paths.append(p)
    finally:
        gmsh.finalize()
    return paths


def test_readers_survive_mutated_files(tmp_path):
    rng = np.random.default_rng(SEED)
    seeds = seed_files(str(tmp_path))
    stats = {"files": 0, "read": 0, "typed_errors": 0, "crashes": [], "readers": set()}
    for src in seeds:
        original = open(src, "rb").read()
        hio.read(src)  # every seed file itself reads
        for k in range(N_PER_SEED):
            data = mutate(original, rng)
            dst = os.path.join(str(tmp_path), "fuzz" + os.path.splitext(src)[1])
            with open(dst, "wb") as f:
                f.write(data)
            try:
                mesh = hio.read(dst)
                mesh.orientations()
                mesh.boundary()
                stats["read"] += 1
                stats["readers"].add(mesh.reader)
            except HexsosError:
                stats["typed_errors"] += 1
            except BaseException as exc:  # noqa: BLE001 - that is what we are looking for
                if isinstance(exc, KeyboardInterrupt):
                    raise
                keep = os.path.join(str(tmp_path), f"crash-{len(stats['crashes'])}" + os.path.splitext(src)[1])
                with open(keep, "wb") as f:
                    f.write(data)
                stats["crashes"].append(f"{os.path.basename(src)} #{k}: {type(exc).__name__}: {exc} ({keep})")
            stats["files"] += 1
    assert stats["crashes"] == []
    assert stats["files"] == N_PER_SEED * len(seeds)
    assert stats["typed_errors"] > 0 and stats["read"] > 0
    assert {"numpy", "meshio"} <= stats["readers"]
