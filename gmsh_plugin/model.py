"""Check and repair the hexahedra of the current Gmsh model, and show the results as Gmsh views.

For people who script Gmsh::

    import gmsh
    from gmsh_plugin import check_model, repair_model

    gmsh.initialize()
    gmsh.open("part.msh")
    result = check_model()          # a hexsos_plugins.CheckResult, views posted
    print(result.summary())
    if result.counts()["invalid"]:
        repair_model(margin=1e-3)   # moves the nodes of the Gmsh model, re-checks, re-posts the views

Only 8-node hexahedra (Gmsh element type 5, whose node order is VTK's, see
:mod:`hexsos_plugins.hexahedron`) are trilinear; higher-order hexahedra (types 12, 17, 92, 93, ...) are
reported as skipped. Every entity of the current model is read; node tags may be any positive integers
(sparse, unsorted): they are mapped to a dense array and back.

det J is measured on the parameter cube [0, 1]^3: Gmsh's own ``minDetJac`` (reference cube [-1, 1]^3)
is this module's value / 8.

Views posted (re-posted in place on every check, so repeated checks do not pile up views):

* ``"hexsos: min det J"``: ElementData, the exact minimum of det J of every hex.
* ``"hexsos: status"``: ElementData, 1 valid, 0 invalid, -1 undecided; drawn only where not valid.
* ``"hexsos: where invalid hexes fold"``: list data, one scalar point (``SP``) per invalid hex at x(u*),
  the world position of its argmin, valued by its min det J.
* ``"hexsos: displacement"`` (after a repair): NodeData, the vector each node moved.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hexsos_plugins.errors import DependencyError, HexsosError, NoHexahedraError

__all__ = [
    "GmshModelError",
    "GmshHexes",
    "VIEW_MIN_DET",
    "VIEW_STATUS",
    "VIEW_ARGMIN",
    "VIEW_DISPLACEMENT",
    "VIEW_NAMES",
    "HEX8",
    "model_hexes",
    "add_hex_mesh",
    "check_model",
    "repair_model",
    "post_views",
    "post_displacement",
    "hexsos_views",
    "remove_views",
    "write_views",
    "world_points",
]

#: Gmsh's element type of the trilinear 8-node hexahedron (node order = VTK order).
HEX8 = 5

VIEW_MIN_DET = "hexsos: min det J"
VIEW_STATUS = "hexsos: status"
VIEW_ARGMIN = "hexsos: where invalid hexes fold"
VIEW_DISPLACEMENT = "hexsos: displacement"
#: Result keys of :func:`post_views` / :func:`hexsos_views` and the view names they stand for.
VIEW_NAMES = {"min_det": VIEW_MIN_DET, "status": VIEW_STATUS, "argmin": VIEW_ARGMIN,
              "displacement": VIEW_DISPLACEMENT}


class GmshModelError(HexsosError, RuntimeError):
    """The Gmsh session cannot be used as asked (not initialized, inconsistent mesh, no result to show)."""


def _gmsh():
    try:
        import gmsh
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise DependencyError("the Gmsh door needs Gmsh's Python API: pip install 'hexsos[gmsh]'") from exc
    if not gmsh.isInitialized():
        raise GmshModelError("Gmsh is not initialized: call gmsh.initialize() and load or build a model first")
    return gmsh


@dataclass
class GmshHexes:
    """The 8-node hexahedra of a Gmsh model as arrays, with the tags to map results back.

    Attributes
    ----------
    points : (N, 3) float64, the coordinates of the nodes the hexes use (only those)
    hexes : (M, 8) int64, rows of ``points`` in VTK (= Gmsh type 5) order
    node_tags : (N,) uint64, the Gmsh tag of each row of ``points`` (sorted ascending)
    element_tags : (M,) uint64, the Gmsh tag of each hex
    model : str, the name of the Gmsh model they come from
    skipped : dict, element type name -> count of higher-order hexahedra that were not checked
    other : dict, element type name -> count of the other 3D elements (tetrahedra, prisms, ...), ignored
    """

    points: np.ndarray
    hexes: np.ndarray
    node_tags: np.ndarray
    element_tags: np.ndarray
    model: str
    skipped: dict = field(default_factory=dict)
    other: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.hexes.shape[0])

    def describe(self) -> str:
        """One line: how many hexahedra and nodes, and what was skipped."""
        s = f"{len(self)} hexahedra, {self.points.shape[0]} nodes (Gmsh model '{self.model}')"
        if self.skipped:
            s += "; skipped (higher order, not trilinear): " + ", ".join(f"{k} {name}" for name, k in
                                                                           self.skipped.items())
        if self.other:
            s += "; ignored: " + ", ".join(f"{k} {name}" for name, k in self.other.items())
        return s


def model_hexes() -> GmshHexes:
    """Read the 8-node hexahedra of every entity of the current Gmsh model.

    Returns
    -------
    GmshHexes
        points / hexes in dense numbering plus the node and element tags to map back.

    Raises
    ------
    NoHexahedraError
        The model holds no 8-node hexahedron (the message names the higher-order ones skipped).
    GmshModelError
        Gmsh is not initialized, or a hex refers to a node the model does not hold.
    """
    gmsh = _gmsh()
    skipped, other = {}, {}
    for etype in gmsh.model.mesh.getElementTypes(3):
        if etype == HEX8:
            continue
        name = gmsh.model.mesh.getElementProperties(etype)[0]
        count = len(gmsh.model.mesh.getElementsByType(etype)[0])
        (skipped if name.lower().startswith("hexahedron") else other)[name] = count
    etags, enodes = gmsh.model.mesh.getElementsByType(HEX8)
    model = gmsh.model.getCurrent()
    if len(etags) == 0:
        msg = f"the Gmsh model '{model}' holds no 8-node hexahedra (element type 5)"
        if skipped:
            msg += ("; it holds higher-order hexahedra (" + ", ".join(f"{k} {name}" for name, k in skipped.items())
                    + "), which are not trilinear and are not checked")
        elif other:
            msg += "; it holds " + ", ".join(f"{k} {name}" for name, k in other.items())
        raise NoHexahedraError(msg)
    etags = np.asarray(etags, dtype=np.uint64)
    enodes = np.asarray(enodes, dtype=np.uint64).reshape(-1, 8)
    used, inverse = np.unique(enodes, return_inverse=True)
    all_tags, coords, _ = gmsh.model.mesh.getNodes(returnParametricCoord=False)
    all_tags = np.asarray(all_tags, dtype=np.uint64)
    coords = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
    order = np.argsort(all_tags, kind="stable")
    sorted_tags = all_tags[order]
    pos = np.searchsorted(sorted_tags, used)
    pos_c = np.minimum(pos, max(sorted_tags.size - 1, 0))
    found = (pos < sorted_tags.size) & (sorted_tags[pos_c] == used) if sorted_tags.size else np.zeros(used.size, bool)
    if not found.all():
        missing = used[~found][:5].tolist()
        raise GmshModelError(f"hexahedra of model '{model}' refer to node tags the model does not hold: {missing}")
    points = coords[order[pos_c]]
    hexes = inverse.reshape(-1, 8).astype(np.int64)
    return GmshHexes(points=points, hexes=hexes, node_tags=used, element_tags=etags, model=model,
                     skipped=skipped, other=other)


def add_hex_mesh(points, hexes, *, model: str | None = "hexsos", node_tags=None, element_tags=None):
    """Load a hex mesh given as arrays into Gmsh as one discrete volume.

    Parameters
    ----------
    points : array_like, shape (N, 3)
    hexes : array_like of int, shape (M, 8), rows of ``points`` in VTK order
    model : str or None, keyword-only
        Name of a new Gmsh model to create and make current; ``None`` adds to the current model.
    node_tags : array_like of int, shape (N,), optional
        Gmsh tag of each point (any distinct positive integers). Default 1..N.
    element_tags : array_like of int, shape (M,), optional
        Gmsh tag of each hex. Default: Gmsh numbers them after the current largest element tag.

    Returns
    -------
    node_tags : (N,) uint64, element_tags : (M,) uint64 (as Gmsh stored them)
    """
    from hexsos_plugins.certify import validate_arrays

    gmsh = _gmsh()
    P, H = validate_arrays(points, hexes)
    ntags = np.arange(1, P.shape[0] + 1, dtype=np.uint64) if node_tags is None else np.asarray(node_tags, np.uint64)
    if ntags.shape != (P.shape[0],) or np.unique(ntags).size != ntags.size or (ntags == 0).any():
        raise GmshModelError(f"node_tags: expected {P.shape[0]} distinct positive integers, found shape {ntags.shape}")
    if model is not None:
        gmsh.model.add(model)
    vol = gmsh.model.addDiscreteEntity(3)
    gmsh.model.mesh.addNodes(3, vol, ntags, P.ravel())
    etags = [] if element_tags is None else np.asarray(element_tags, dtype=np.uint64)
    gmsh.model.mesh.addElementsByType(vol, HEX8, etags, ntags[H].ravel())
    return ntags, np.asarray(gmsh.model.mesh.getElementsByType(HEX8, vol)[0], dtype=np.uint64)


def world_points(points, hexes, uvw) -> np.ndarray:
    """x(u, v, w) of the trilinear map of each hex: (K, 3) world points of (K, 3) parameter points.

    ``hexes`` (K, 8) are the hexes the parameter points belong to (VTK order, parameter cube [0, 1]^3).
    """
    from hexsos_plugins.hexahedron import map_points

    return map_points(np.asarray(points, dtype=np.float64)[np.asarray(hexes, dtype=np.int64)], uvw)


# --- views ---------------------------------------------------------------------------------------------

def hexsos_views() -> dict:
    """Tags of the hexsos views in the session, by key of :data:`VIEW_NAMES` (absent keys: no such view)."""
    gmsh = _gmsh()
    found = {}
    for tag in gmsh.view.getTags():
        name = gmsh.option.getString(f"View[{gmsh.view.getIndex(tag)}].Name")
        for key, vname in VIEW_NAMES.items():
            if name == vname:
                found[key] = int(tag)
    return found


def remove_views(keys=None) -> None:
    """Remove the hexsos views (all of them, or those of the given keys of :data:`VIEW_NAMES`)."""
    gmsh = _gmsh()
    for key, tag in hexsos_views().items():
        if keys is None or key in keys:
            gmsh.view.remove(tag)


def _new_view(key: str, existing: dict) -> int:
    """A fresh view for ``key``, taking over the tag of the previous one (so tags stay stable)."""
    gmsh = _gmsh()
    old = existing.get(key)
    if old is not None:
        gmsh.view.remove(old)
        return int(gmsh.view.add(VIEW_NAMES[key], old))
    return int(gmsh.view.add(VIEW_NAMES[key]))


def _gmsh_data(result, element_tags, points, hexes, model):
    info = result.extra.get("gmsh") if isinstance(getattr(result, "extra", None), dict) else None
    if element_tags is None:
        if info is None:
            raise GmshModelError("post_views: the result does not come from check_model; pass element_tags, "
                                 "points and hexes")
        element_tags = info.element_tags
    if points is None or hexes is None:
        if info is None:
            raise GmshModelError("post_views: pass points and hexes (needed to place the argmin points)")
        points, hexes = info.points, info.hexes
    if model is None:
        model = info.model if info is not None else _gmsh().model.getCurrent()
    element_tags = np.asarray(element_tags, dtype=np.uint64)
    if element_tags.shape != (len(result),):
        raise GmshModelError(f"post_views: expected {len(result)} element tags (one per hex), "
                             f"found shape {element_tags.shape}")
    return element_tags, np.asarray(points, np.float64), np.asarray(hexes, np.int64), model


def post_views(result, element_tags=None, points=None, hexes=None, *, model: str | None = None) -> dict:
    """Post the results of a check as Gmsh views (replacing earlier hexsos views, keeping their tags).

    Parameters
    ----------
    result : hexsos_plugins.CheckResult
        From :func:`check_model` (which carries the tags and arrays), or from ``hexsos_plugins.check``
        on arrays that match the Gmsh model (then pass the three arrays below).
    element_tags : array_like of int, shape (M,), optional
        Gmsh tag of each hex of the result.
    points : array_like, shape (N, 3), optional
    hexes : array_like of int, shape (M, 8), optional
        The arrays the result was computed on (to place the argmin points in world coordinates).
    model : str, optional, keyword-only
        The Gmsh model the element tags belong to. Default: the result's, else the current model.

    Returns
    -------
    dict
        View tags by key: ``"min_det"``, ``"status"`` (ElementData views) and ``"argmin"`` (list data: one
        scalar point per invalid hex at the world position of its argmin, valued by its min det J).
    """
    gmsh = _gmsh()
    element_tags, points, hexes, model = _gmsh_data(result, element_tags, points, hexes, model)
    existing = hexsos_views()
    views = {}

    views["min_det"] = tag = _new_view("min_det", existing)
    gmsh.view.addHomogeneousModelData(tag, 0, model, "ElementData", element_tags,
                                      np.ascontiguousarray(result.min_det, dtype=np.float64), numComponents=1)
    # a diverging scale centred on 0 would hide the magnitudes; keep Gmsh's default rainbow, but hidden:
    # the status view below shows the invalid hexes, which the valid ones around them would cover
    gmsh.view.option.setNumber(tag, "Visible", 0)

    views["status"] = tag = _new_view("status", existing)
    gmsh.view.addHomogeneousModelData(tag, 0, model, "ElementData", element_tags,
                                      np.asarray(result.status, dtype=np.float64), numComponents=1)
    # draw only the hexes that are not valid (status -1 or 0); valid ones (1) lie outside the range
    gmsh.view.option.setNumber(tag, "RangeType", 2)
    gmsh.view.option.setNumber(tag, "CustomMin", -1.0)
    gmsh.view.option.setNumber(tag, "CustomMax", 0.0)
    gmsh.view.option.setNumber(tag, "SaturateValues", 0)
    gmsh.view.option.setNumber(tag, "IntervalsType", 3)  # discrete colours
    gmsh.view.option.setNumber(tag, "NbIso", 2)
    gmsh.view.option.setString(tag, "Format", "%g")

    bad = np.flatnonzero(np.asarray(result.status) == 0)
    views["argmin"] = tag = _new_view("argmin", existing)
    if bad.size:
        xyz = world_points(points, hexes[bad], np.asarray(result.argmin)[bad])
        data = np.column_stack([xyz, np.asarray(result.min_det)[bad]]).ravel()
        gmsh.view.addListData(tag, "SP", int(bad.size), data)
    else:
        gmsh.view.addListData(tag, "SP", 0, [])
    gmsh.view.option.setNumber(tag, "PointType", 1)  # spheres
    gmsh.view.option.setNumber(tag, "PointSize", 12)
    gmsh.view.option.setNumber(tag, "ShowScale", 0)
    # colormap 0 is all black; inverted, all white: white spheres stand out on the dark red invalid hexes
    gmsh.view.option.setNumber(tag, "ColormapNumber", 0)
    gmsh.view.option.setNumber(tag, "ColormapInvert", 1)
    return views


def post_displacement(node_tags, displacement, *, model: str | None = None) -> int:
    """Post a NodeData vector view ``"hexsos: displacement"`` (how far each node moved); returns its tag."""
    gmsh = _gmsh()
    node_tags = np.asarray(node_tags, dtype=np.uint64)
    d = np.ascontiguousarray(displacement, dtype=np.float64).reshape(-1, 3)
    if d.shape[0] != node_tags.size:
        raise GmshModelError(f"post_displacement: expected {node_tags.size} displacement vectors, found {d.shape[0]}")
    tag = _new_view("displacement", hexsos_views())
    gmsh.view.addHomogeneousModelData(tag, 0, model or gmsh.model.getCurrent(), "NodeData", node_tags, d.ravel(),
                                      numComponents=3)
    gmsh.view.option.setNumber(tag, "Visible", 0)
    return tag


def write_views(path: str) -> list:
    """Write the hexsos views to ``path``; returns the files written.

    Any format ``gmsh.view.write`` takes. ``.pos`` (Gmsh's post-processing format) holds every view in one file.
    ``.msh`` holds the mesh once and the element / node data views (min det J, status, displacement); the
    argmin points are a list-based view, which Gmsh cannot put in a ``.msh`` beside a mesh (it would overwrite
    it), so they go to ``<path without .msh>-argmin.pos`` when there are any.
    """
    import os

    from hexsos_plugins.errors import MeshWriteError

    gmsh = _gmsh()
    views = hexsos_views()
    if not views:
        raise GmshModelError("no hexsos views to write: run a check first")
    order = [k for k in VIEW_NAMES if k in views]
    stem, ext = os.path.splitext(path)
    written = []
    try:
        if ext.lower() == ".msh":
            save_mesh = gmsh.option.getNumber("PostProcessing.SaveMesh")
            try:
                model_based = [k for k in order if k != "argmin"]
                for i, key in enumerate(model_based):
                    gmsh.option.setNumber("PostProcessing.SaveMesh", 1 if i == 0 else 0)
                    gmsh.view.write(views[key], path, append=i > 0)
            finally:
                gmsh.option.setNumber("PostProcessing.SaveMesh", save_mesh)
            written.append(path)
            _, counts, _ = gmsh.view.getListData(views["argmin"]) if "argmin" in views else ([], [], [])
            if sum(int(c) for c in counts):
                gmsh.view.write(views["argmin"], stem + "-argmin.pos")
                written.append(stem + "-argmin.pos")
        else:
            for i, key in enumerate(order):
                gmsh.view.write(views[key], path, append=i > 0)
            written.append(path)
    except Exception as exc:  # Gmsh raises plain Exception
        raise MeshWriteError(f"could not write the views to {path}: {' '.join(str(exc).split())}") from exc
    return written


# --- check and repair ----------------------------------------------------------------------------------

def check_model(*, method: str = "auto", relaxation: str = "quad2", post_views: bool = True, progress=None):
    """Check every 8-node hexahedron of the current Gmsh model (all entities).

    Parameters
    ----------
    method, relaxation : keyword-only
        Passed to :func:`hexsos_plugins.check` (``"auto"`` / ``"sos"``; ``"quad2"`` / ``"paper"``).
    post_views : bool, keyword-only
        Post (or re-post) the views ``"hexsos: min det J"``, ``"hexsos: status"`` and the argmin points of
        the invalid hexes. Default True.
    progress : callable(done, total), optional

    Returns
    -------
    hexsos_plugins.CheckResult
        Arrays in the order of ``result.extra["gmsh"].element_tags`` (a :class:`GmshHexes`, which also holds
        the node tags, the dense arrays and the skipped higher-order hexahedra); the posted view tags are in
        ``result.extra["gmsh_views"]``.

    Raises
    ------
    NoHexahedraError, GmshModelError, InvalidInputError (bad method / relaxation)
    """
    from hexsos_plugins.certify import check

    hx = model_hexes()
    result = check(hx.points, hx.hexes, method=method, relaxation=relaxation, progress=progress)
    result.extra["gmsh"] = hx
    result.extra["gmsh_views"] = _post(result) if post_views else {}
    return result


def _post(result):
    return post_views(result)


def _other_cells(gmsh, hx):
    """The model's 3-D elements that are not 8-node hexahedra, as (meshio name, conn) in VTK order over the hex
    nodes extended by theirs: returns (points, node_tags, cells, skipped) -- ``skipped`` counts elements of
    types hexsos does not know (left out: their nodes are pinned)."""
    from hexsos_plugins.elements import ELEMENTS

    by_gmsh = {el.gmsh_type: el for el in ELEMENTS.values()}
    raw, unknown = [], []
    for etype in gmsh.model.mesh.getElementTypes(3):
        if etype == HEX8:
            continue
        _, nodes = gmsh.model.mesh.getElementsByType(etype)
        nodes = np.asarray(nodes, dtype=np.uint64)
        el = by_gmsh.get(int(etype))
        if el is None:
            unknown.append(nodes)
            continue
        raw.append((el, nodes.reshape(-1, el.n_nodes)[:, list(el.gmsh_to_vtk)]))
    extra = np.unique(np.concatenate([c.ravel() for _, c in raw] + unknown)) if (raw or unknown) else \
        np.zeros(0, np.uint64)
    extra = np.setdiff1d(extra, hx.node_tags)
    tags = np.concatenate([hx.node_tags, extra])
    points = hx.points
    if extra.size:
        coords = np.array([gmsh.model.mesh.getNode(int(t))[0] for t in extra], dtype=np.float64).reshape(-1, 3)
        points = np.vstack([hx.points, coords])
    order = np.argsort(tags, kind="stable")
    st = tags[order]

    def dense(t):
        return order[np.searchsorted(st, t)]

    cells = [(el.name, dense(c).astype(np.int64)) for el, c in raw]
    pinned = np.zeros(points.shape[0], dtype=bool)
    for u in unknown:
        pinned[dense(u)] = True
    return points, tags, cells, pinned


def repair_model(*, repair_method: str = "optimize", boundary: str | None = None, min_sj=None,
                 rho: float = 200.0, margin=None, pin_boundary: bool = False, max_iter=None,
                 method: str = "auto", relaxation: str = "quad2", progress=None, post_views: bool = True,
                 pin_shared: bool | None = None, time_limit=None):
    """Repair the current Gmsh model: move its nodes, re-check, re-post the views.

    Parameters
    ----------
    repair_method : {"optimize", "paper"}, keyword-only
        :func:`hexsos_plugins.repair`'s ``method``: untangle, raise the quality, certify (default), or the
        paper's Algorithms 1 and 2.
    boundary, min_sj, time_limit : keyword-only
        Passed to :func:`hexsos_plugins.repair` (default boundary: ``"slide"`` for optimize, ``"free"`` for
        paper; ``"fixed"`` with ``pin_boundary=True``).
    rho, margin, max_iter, relaxation, progress : keyword-only
        Passed to :func:`hexsos_plugins.repair`; ``method`` is the kernel's (``"auto"`` / ``"sos"``, the
        paper's repair's u* finder).
    post_views : bool, keyword-only
        Re-post the check views of the repaired model and a ``"hexsos: displacement"`` NodeData view.
    pin_shared : bool, optional, keyword-only
        True: keep fixed every node the hexes share with other 3-D elements. Default (None): the repair decides
        -- linear tetrahedra, prisms and pyramids are repaired with the hexes by ``"optimize"`` (their nodes move
        only by steps that keep them valid), their nodes pinned by ``"paper"``; nodes of elements of other types
        (higher order) are pinned. Every 3-D element is checked: the repair succeeds only if all are valid.

    Only nodes that moved are written back, with ``gmsh.model.mesh.setNode``. Parametric coordinates of nodes
    on CAD entities are left as they were.

    Returns
    -------
    RepairResult
        The kernel's result; ``extra`` also holds ``"model_check"`` (the check of the hexes read back from Gmsh),
        ``"gmsh"`` (the :class:`GmshHexes` the repair started from), ``"moved_node_tags"``, and
        ``"other_cells"`` (the final check of the other 3-D elements).
    """
    from hexsos_plugins import repair

    gmsh = _gmsh()
    hx = model_hexes()
    points, tags, cells, pinned = _other_cells(gmsh, hx)
    if pin_shared:
        for _, conn in cells:
            pinned[conn.ravel()] = True
    # a kernel method as repair_method (the earlier signature) means the paper's repair
    res = repair(points, hx.hexes, cells=cells, method=repair_method, boundary=boundary, min_sj=min_sj,
                 rho=rho, margin=margin, pin_boundary=pin_boundary, max_iter=max_iter, kernel_method=method,
                 relaxation=relaxation, progress=progress, pinned=pinned if pinned.any() else None,
                 time_limit=time_limit)
    new = np.asarray(res.points, dtype=np.float64)
    moved = np.flatnonzero(np.any(new != points, axis=1))
    for i in moved:
        gmsh.model.mesh.setNode(int(tags[i]), new[i], [])
    after = check_model(method=method, relaxation=relaxation, post_views=post_views)
    n = hx.points.shape[0]
    if post_views:
        post_displacement(hx.node_tags, (new - points)[:n], model=hx.model)
        after.extra["gmsh_views"] = hexsos_views()
    res.extra["model_check"] = after
    res.extra["gmsh"] = hx
    res.extra["moved_node_tags"] = tags[moved]
    return res
