import atexit
import os
import shutil
import sys
import tempfile

# the test helpers (oracle.py) live beside the tests
sys.path.insert(0, os.path.dirname(__file__))

import numpy as np  # noqa: E402
import pytest  # noqa: E402

# hexsos records the environments it runs in (for the ParaView plugin loaded by hand) under XDG_CONFIG_HOME:
# the suite records into a directory of its own, never into the user's home (subprocesses inherit it)
# (removed when the process ends: each pytest process, xdist's workers too, made one and left it behind)
os.environ["XDG_CONFIG_HOME"] = tempfile.mkdtemp(prefix="hexsos-tests-config-")
atexit.register(shutil.rmtree, os.environ["XDG_CONFIG_HOME"], True)

SHARED = os.path.normpath(os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data"))
BUNNY = os.path.join(SHARED, "bunny.vtk")


def published(name):
    """The path of a published mesh of ``../shared/data`` (``name`` relative to it), read in place and never copied;
    skips the calling test when it is absent."""
    path = os.path.join(SHARED, name)
    if not os.path.exists(path):
        pytest.skip(f"{path} is absent (published meshes are read in place, never copied)")
    return path


def tet_grid(n):
    """A cube [0, n]^3 cut into n^3 cubes of 6 tetrahedra each (Kuhn), positively oriented."""
    g = np.arange(n + 1)
    P = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3).astype(float)
    idx = lambda i, j, k: (i * (n + 1) + j) * (n + 1) + k  # noqa: E731
    T = []
    paths = [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]
    for i in range(n):
        for j in range(n):
            for k in range(n):
                for p in paths:
                    v = np.array([i, j, k])
                    verts = [idx(*v)]
                    for a in p:
                        v = v.copy()
                        v[a] += 1
                        verts.append(idx(*v))
                    T.append(verts)
    T = np.array(T)
    X = P[T]
    d = np.einsum("ij,ij->i", X[:, 1] - X[:, 0], np.cross(X[:, 2] - X[:, 0], X[:, 3] - X[:, 0]))
    T[d < 0] = T[d < 0][:, [0, 2, 1, 3]]
    return P, T


def write_box_in_two_groups(gmsh, path):
    """Mesh a unit box into tets in the open Gmsh session, its volume in two physical groups, and save it as MSH 2.2
    at ``path``: Gmsh writes every element once per group, so the file holds each tet twice."""
    gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
    gmsh.model.occ.synchronize()
    gmsh.model.addPhysicalGroup(3, [1], 1)
    gmsh.model.addPhysicalGroup(3, [1], 2)
    gmsh.option.setNumber("Mesh.MeshSizeMax", 0.5)
    gmsh.model.mesh.generate(3)
    gmsh.option.setNumber("Mesh.MshFileVersion", 2.2)
    gmsh.write(str(path))


@pytest.fixture
def bunny_path():
    if not os.path.exists(BUNNY):
        pytest.skip(f"{BUNNY} is absent (the paper's bunny mesh is read in place, never copied)")
    return BUNNY


# the files that take longest start first, longest first (a wheel installed in a fresh venv with ParaView's GUI: 268 s
# of the suite's 989 s of work on 2026-12-03; the repair's optimizer: 166 s): with one worker per core (pyproject's
# addopts), a long file started last leaves the other core idle at the end (the suite: 10.8 min in xdist's own order of
# files, by test count, which ran the wheel's last; 8.8 min with it first)
LONGEST_FIRST = ("test_doors_wheel.py", "test_repair_optimize.py")


def pytest_collection_modifyitems(config, items):
    rank = {name: k for k, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(LONGEST_FIRST)))
