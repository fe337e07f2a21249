"""Curved meshes Gmsh's own curving inverts, generated with Gmsh as users get them: ``Mesh.HighOrderOptimize`` 0, then
``setOrder`` (Gmsh moves the high-order nodes of the boundary elements onto the geometry and often inverts the
cells behind them).

    python -m comparison.curved_meshes KIND OUT.msh      (KIND: shell, cylinder, torus, torus_coarse)

Each mesh gets one physical volume per volume entity (``vol``), so that a repair can be seen to keep it.
:func:`true_distance` is the distance of points to the exact geometry.
"""

from __future__ import annotations

import sys

import numpy as np

#: kind -> (order, mesh size, what it is)
KINDS = {
    "shell": (2, 0.35, "spherical shell r 0.9-1"),
    "cylinder": (2, 0.35, "cylinder r 1, h 1, all-hex (subdivision of recombined tets)"),
    "torus": (3, 0.15, "torus R 1, r 0.15"),
    "torus_coarse": (3, 0.3, "torus R 1, r 0.15"),
}


def build(kind: str) -> None:
    """Mesh the model of ``kind`` in the current Gmsh session (gmsh initialized, model empty)."""
    import gmsh

    order, size, _ = KINDS[kind]
    gmsh.option.setNumber("Mesh.HighOrderOptimize", 0)
    if kind == "shell":
        a = gmsh.model.occ.addSphere(0, 0, 0, 1)
        b = gmsh.model.occ.addSphere(0, 0, 0, 0.9)
        gmsh.model.occ.cut([(3, a)], [(3, b)])
    elif kind == "cylinder":
        gmsh.model.occ.addCylinder(0, 0, 0, 0, 0, 1, 1)
        gmsh.option.setNumber("Mesh.SubdivisionAlgorithm", 2)
        gmsh.option.setNumber("Mesh.RecombineAll", 1)
    else:
        gmsh.model.occ.addTorus(0, 0, 0, 1, 0.15)
    gmsh.model.occ.synchronize()
    gmsh.option.setNumber("Mesh.MeshSizeMax", size)
    gmsh.model.mesh.generate(3)
    gmsh.model.mesh.setOrder(order)
    for _, tag in gmsh.model.getEntities(3):
        gmsh.model.addPhysicalGroup(3, [tag], name="vol")


def generate(kind: str, path: str) -> None:
    """Write the mesh of ``kind`` to ``path`` (Gmsh's msh, every element saved)."""
    import gmsh

    gmsh.initialize(["-noenv"], readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        build(kind)
        gmsh.option.setNumber("Mesh.SaveAll", 1)
        gmsh.option.setNumber("Mesh.Binary", 0)
        gmsh.write(path)
    finally:
        gmsh.finalize()


def true_distance(kind: str, X) -> np.ndarray:
    """Distance of the points X (n, 3) to the boundary of the exact geometry of ``kind``."""
    X = np.asarray(X, dtype=np.float64)
    if kind == "shell":
        r = np.linalg.norm(X, axis=1)
        return np.minimum(np.abs(r - 1.0), np.abs(r - 0.9))
    if kind == "cylinder":
        rho = np.hypot(X[:, 0], X[:, 1])
        z = X[:, 2]
        side = np.abs(rho - 1.0)
        cap = np.where(rho <= 1.0, np.minimum(np.abs(z), np.abs(z - 1.0)), np.inf)
        rim = np.minimum(np.hypot(rho - 1.0, z), np.hypot(rho - 1.0, z - 1.0))
        inside_z = (z >= 0) & (z <= 1)
        return np.minimum(np.where(inside_z, side, rim), np.minimum(cap, rim))
    rho = np.hypot(X[:, 0], X[:, 1])
    return np.abs(np.hypot(rho - 1.0, X[:, 2]) - 0.15)


def diagonal(kind: str) -> float:
    """The bounding-box diagonal of the exact geometry."""
    return {"shell": 2 * np.sqrt(3.0), "cylinder": np.sqrt(8.0 + 1.0), "torus": np.sqrt(2 * 2.3 ** 2 + 0.3 ** 2),
            "torus_coarse": np.sqrt(2 * 2.3 ** 2 + 0.3 ** 2)}[kind]


if __name__ == "__main__":
    generate(sys.argv[1], sys.argv[2])
