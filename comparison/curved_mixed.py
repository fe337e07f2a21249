"""Gmsh mixed meshes of any order (hexahedra, prisms, tetrahedra, pyramids), curved and perturbed: the test and
benchmark data of the curved cells. Generated with Gmsh (``setOrder``); nothing third-party is stored.

Gmsh 4.15 builds prisms of order 3 and above (``setOrder``) but cannot evaluate them: every query that needs
their basis (``getElementProperties``, ``getJacobians``, ``getElementQualities``) fails with "FaceClosureFull not
implemented for prisms of order 3". Corner nodes are therefore taken from hexsos' registry here, not from Gmsh.
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["build_mixed", "write_mixed", "CORNERS"]

#: primary (corner) nodes per Gmsh element family, by the family's linear type
CORNERS = {"Point": 1, "Line": 2, "Triangle": 3, "Quadrilateral": 4, "Tetrahedron": 4, "Hexahedron": 8, "Prism": 6,
           "Pyramid": 5}


def _corners(gmsh, etype):
    from hexsos_plugins.cells.elements import ELEMENTS

    for el in ELEMENTS.values():
        if el.gmsh_type == etype:
            return {"tet": 4, "cube": 8, "prism": 6, "pyramid": 5}[el.domain]
    return int(gmsh.model.mesh.getElementProperties(etype)[5])


def build_mixed(gmsh, order, *, size=0.35, curve=0.03, noise=0.0, seed=0, incomplete=False, bottom=False):
    """The mixed mesh of two extruded layers (hexahedra, prisms) under an unstructured cap (tetrahedra, pyramids),
    at ``order``; the high-order nodes (not the corners) moved by ``curve`` sin(...) (a curved mesh) and by
    Gaussian ``noise`` (times the mesh size; noise makes some cells invalid). ``incomplete``: Gmsh's incomplete
    elements (``Mesh.SecondOrderIncomplete``: corner and edge nodes only, at any order); ``bottom``: the bottom
    faces a physical group too (21, "Bottom")."""
    gmsh.model.add(f"mixed{order}")
    g = gmsh.model.geo
    p = [g.addPoint(x, y, 0, size) for x, y in ((0, 0), (1, 0), (1, 1), (0, 1), (2, 0), (2, 1))]
    lines = [g.addLine(p[0], p[1]), g.addLine(p[1], p[2]), g.addLine(p[2], p[3]), g.addLine(p[3], p[0]),
             g.addLine(p[1], p[4]), g.addLine(p[4], p[5]), g.addLine(p[5], p[2])]
    s1 = g.addPlaneSurface([g.addCurveLoop(lines[:4])])
    s2 = g.addPlaneSurface([g.addCurveLoop([lines[4], lines[5], lines[6], -lines[1]])])
    g.mesh.setTransfiniteSurface(s1)
    for c in lines[:4]:
        g.mesh.setTransfiniteCurve(c, 4)
    g.mesh.setRecombine(2, s1)
    e1 = g.extrude([(2, s1), (2, s2)], 0, 0, 0.6, [2], recombine=True)
    g.extrude([e1[0], e1[6]], 0, 0, 0.7)
    g.synchronize()
    vols = [t for _, t in gmsh.model.getEntities(3)]
    gmsh.model.addPhysicalGroup(3, vols[:2], 11, "Layers")
    gmsh.model.addPhysicalGroup(3, vols[2:], 12, "Cap")
    if bottom:
        gmsh.model.addPhysicalGroup(2, [s1, s2], 21, "Bottom")
    gmsh.option.setNumber("Mesh.SecondOrderIncomplete", int(incomplete))
    gmsh.model.mesh.generate(3)
    if order > 1:
        gmsh.model.mesh.setOrder(order)
    rng = np.random.default_rng(seed)
    tags, xyz, _ = gmsh.model.mesh.getNodes()
    xyz = np.asarray(xyz).reshape(-1, 3)
    corner_tags = set()
    for t in gmsh.model.mesh.getElementTypes():
        k = _corners(gmsh, t)
        nodes = np.asarray(gmsh.model.mesh.getElementsByType(t)[1])
        nodes = nodes.reshape(len(gmsh.model.mesh.getElementsByType(t)[0]), -1)
        corner_tags.update(nodes[:, :k].ravel().tolist())
    for tag, x in zip(tags, xyz):
        if int(tag) not in corner_tags:
            d = curve * np.array([np.sin(3 * x[1] + x[2]), np.sin(2 * x[2] + x[0]), np.sin(3 * x[0] + x[1])])
            d += noise * size / max(order, 1) * rng.standard_normal(3)
            gmsh.model.mesh.setNode(int(tag), (x + d).tolist(), [])


def write_mixed(path, order, *, version=4.1, binary=False, **kw):
    """Build the mixed mesh of ``order`` (see :func:`build_mixed`) and write it with Gmsh."""
    import gmsh

    gmsh.initialize([], readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        build_mixed(gmsh, order, **kw)
        gmsh.option.setNumber("Mesh.MshFileVersion", version)
        gmsh.option.setNumber("Mesh.Binary", int(binary))
        gmsh.write(os.fspath(path))
    finally:
        gmsh.finalize()
    return path
