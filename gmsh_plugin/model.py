"""Check and repair the 3-D elements of the current Gmsh model, and show the results as Gmsh views.

For people who script Gmsh::

    import gmsh
    from gmsh_plugin import check_model, repair_model

    gmsh.initialize()
    gmsh.open("part.msh")
    result = check_model()          # a hexsos_plugins.CheckResult, views posted
    print(result.summary())
    if result.counts()["invalid"]:
        repair_model(margin=1e-3)   # moves the nodes of the Gmsh model, re-checks, re-posts the views

Every 3-D element type of :mod:`hexsos_plugins.cells.elements` is checked: tetrahedra, pyramids, prisms and
hexahedra, linear and quadratic (Gmsh types 4, 11, 7, 19, 14, 6, 18, 13, 5, 17, 12), their nodes reordered
from Gmsh's numbering to VTK's (the 14-node pyramid, which VTK lacks, keeps Gmsh's); other 3-D types (orders
above 2) are counted as not checked. Every entity of the current model is read; node tags may be any positive integers (sparse,
unsorted): they are mapped to a dense array and back.

det J is measured on VTK's reference elements (hexahedra: the parameter cube [0, 1]^3): Gmsh's own
``minDetJac`` is this module's value times :attr:`hexsos_plugins.cells.elements.Element.gmsh_factor` (1/8 for
hexahedra, whose Gmsh reference cube is [-1, 1]^3; 1/2 for prisms; 1 for tetrahedra; 1/4 for pyramids).

Views posted (re-posted in place on every check, so repeated checks do not pile up views):

* ``"hexsos: min det J"``: ElementData, the exact minimum of det J of every checked element.
* ``"hexsos: status"``: ElementData, 1 valid, 0 invalid, -1 undecided; drawn only where not valid, invalid
  dark red and undecided orange (no colour bar: the key says what the colours mean).
* ``"hexsos: invalid inside only"``: ElementData over the invalid elements that are valid at every node (what
  node checks miss), value 0, drawn magenta just around them.
* ``"hexsos: written mirrored"``: ElementData over the elements written in the mirrored node order (they fold
  over their neighbours whatever their own verdicts; :func:`check_model`), value 0, drawn blue around them.
* ``"hexsos: key"``: two lines of text at the top of the graphics naming the colours, with the counts (a third
  when elements are written mirrored).
* ``"hexsos: where invalid elements fold"``: list data, one scalar point (``SP``) per invalid element at
  x(u*), the world position of its argmin, valued by its min det J.
* ``"hexsos: displacement"`` (after a repair): NodeData, the vector each node moved.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hexsos_plugins.errors import DependencyError, HexsosError, NoHexahedraError

__all__ = [
    "GmshModelError",
    "GmshCells",
    "GmshHexes",
    "VIEW_MIN_DET",
    "VIEW_STATUS",
    "VIEW_ARGMIN",
    "VIEW_DISPLACEMENT",
    "VIEW_INSIDE_ONLY",
    "VIEW_KEY",
    "VIEW_MIRRORED",
    "VIEW_NAMES",
    "VIEW_SAFE_STEP",
    "safe_step_model",
    "STATUS_RGB",
    "HEX8",
    "model_cells",
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
VIEW_ARGMIN = "hexsos: where invalid elements fold"
VIEW_DISPLACEMENT = "hexsos: displacement"
VIEW_INSIDE_ONLY = "hexsos: invalid inside only"
VIEW_KEY = "hexsos: key"
VIEW_MIRRORED = "hexsos: written mirrored"
#: Result keys of :func:`post_views` / :func:`hexsos_views` and the view names they stand for.
VIEW_NAMES = {"min_det": VIEW_MIN_DET, "status": VIEW_STATUS, "argmin": VIEW_ARGMIN,
              "displacement": VIEW_DISPLACEMENT, "inside_only": VIEW_INSIDE_ONLY, "key": VIEW_KEY,
              "mirrored": VIEW_MIRRORED}
#: Colours of the status view (undecided, invalid), of the invalid-inside-only elements and of those written in
#: the mirrored node order, as RGB 0-255: the other doors' (orange undecided, red invalid, magenta invalid inside
#: only), and blue
STATUS_RGB = {"undecided": (255, 140, 0), "invalid": (170, 0, 0), "inside_only": (255, 0, 255),
              "mirrored": (0, 90, 255)}


class GmshModelError(HexsosError, RuntimeError):
    """The Gmsh session cannot be used as asked (not initialized, inconsistent mesh, no result to show)."""


def gmsh_api():
    try:
        import gmsh
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise DependencyError("the Gmsh door needs Gmsh's Python API: pip install 'hexsos[gmsh]'") from exc
    if not gmsh.isInitialized():
        raise GmshModelError("Gmsh is not initialized: call gmsh.initialize() and load or build a model first")
    return gmsh


@dataclass
class GmshCells:
    """The 3-D elements of a Gmsh model as arrays, with the tags to map results back.

    Attributes
    ----------
    points : (N, 3) float64, the coordinates of the nodes the 3-D elements use (only those)
    cells : list of (type, conn): one block per element type hexsos checks (meshio names, e.g. ``"hexahedron"``,
        ``"hexahedron20"``, ``"tetra"``, ``"wedge"``), ``conn`` (M_t, n_t) rows of ``points`` in VTK order
    node_tags : (N,) uint64, the Gmsh tag of each row of ``points`` (sorted ascending)
    element_tags : (M,) uint64, the Gmsh tag of each checked element, blocks in the order of ``cells``
    model : str, the name of the Gmsh model they come from
    skipped : dict, Gmsh element type name -> count of 3-D elements of types hexsos does not check (e.g.
        third-order elements); their nodes are in ``points`` and flagged in ``skipped_nodes``
    skipped_nodes : (N,) bool, nodes of skipped elements (a repair keeps them fixed)
    """

    points: np.ndarray
    cells: list
    node_tags: np.ndarray
    element_tags: np.ndarray
    model: str
    skipped: dict = field(default_factory=dict)
    skipped_nodes: np.ndarray = None

    def __len__(self) -> int:
        return int(sum(c.shape[0] for _, c in self.cells))

    @property
    def hexes(self) -> np.ndarray:
        """(M, 8) the 8-node hexahedra (VTK = Gmsh type 5 order); (0, 8) when the model has none."""
        blocks = [c for t, c in self.cells if t == "hexahedron"]
        return blocks[0] if blocks else np.zeros((0, 8), dtype=np.int64)

    @property
    def hex_element_tags(self) -> np.ndarray:
        """The Gmsh tags of :attr:`hexes`."""
        off = 0
        for t, c in self.cells:
            if t == "hexahedron":
                return self.element_tags[off:off + c.shape[0]]
            off += c.shape[0]
        return np.zeros(0, dtype=np.uint64)

    def counts(self) -> dict:
        """Elements checked per type (meshio names)."""
        return {t: int(c.shape[0]) for t, c in self.cells}

    def describe(self) -> str:
        """One line: how many elements of which types and nodes, and what was not checked."""
        s = (f"{len(self)} elements (" + ", ".join(f"{k} {t}" for t, k in self.counts().items()) +
             f"), {self.points.shape[0]} nodes (Gmsh model '{self.model}')")
        if self.skipped:
            s += "; not checked (no exact element): " + ", ".join(f"{k} {name}" for name, k in self.skipped.items())
        return s


#: The name of :class:`GmshCells` in earlier versions (hexahedra only).
GmshHexes = GmshCells


def model_cells() -> GmshCells:
    """Read every 3-D element of every entity of the current Gmsh model.

    Every type of :data:`hexsos_plugins.cells.elements.ELEMENTS` (tetrahedra, pyramids, prisms, hexahedra of orders
    1 to 5, quadratic serendipity cells) is read with its nodes reordered from Gmsh's numbering to VTK's; 3-D
    elements of other types (orders above 5) are counted in ``skipped``.

    Raises
    ------
    NoCellsError
        The model holds no 3-D element hexsos checks (the message says what it holds).
    GmshModelError
        Gmsh is not initialized, or an element refers to a node the model does not hold.
    """
    from hexsos_plugins.cells.elements import ELEMENTS
    from hexsos_plugins.errors import NoCellsError

    gmsh = gmsh_api()
    by_gmsh = {el.gmsh_type: el for el in ELEMENTS.values()}
    raw, skipped, skipped_raw = [], {}, []
    for etype in gmsh.model.mesh.getElementTypes(3):
        etags, enodes = gmsh.model.mesh.getElementsByType(etype)
        el = by_gmsh.get(int(etype))
        enodes = np.asarray(enodes, dtype=np.uint64)
        if el is None:
            try:
                name = gmsh.model.mesh.getElementProperties(etype)[0]
            except Exception:  # Gmsh 4.15 cannot describe prisms of order >= 3 ("FaceClosureFull")
                name = f"Gmsh element type {int(etype)}"
            skipped[name] = len(etags)
            skipped_raw.append(enodes)
            continue
        conn = enodes.reshape(-1, el.n_nodes)[:, list(el.gmsh_to_vtk)]
        raw.append((el.name, np.asarray(etags, dtype=np.uint64), conn))
    model = gmsh.model.getCurrent()
    if not raw:
        msg = f"the Gmsh model '{model}' holds no 3-D elements hexsos checks"
        if skipped:  # a 3-D mesh, of an order (or type) with no exact element here: say so, not "mesh it"
            msg += ("; it holds " + ", ".join(f"{k} {name}" for name, k in skipped.items())
                    + ", of a type hexsos has no exact element for (it checks tetrahedra, pyramids, prisms and "
                      "hexahedra of orders 1 to 5, complete, and the serendipity cells of order 2): set the mesh order to 5 or "
                      "less (Mesh.ElementOrder) and mesh again")
            raise NoCellsError(msg)
        dims = [d for d in (2, 1, 0) if len(gmsh.model.mesh.getElementTypes(d))]
        msg += f" (its elements are of dimension {', '.join(map(str, dims))})" if dims else " (it has no mesh)"
        raise NoCellsError(msg + ": mesh it in 3-D first")
    used = np.unique(np.concatenate([c.ravel() for _, _, c in raw] + skipped_raw))
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
        raise GmshModelError(f"3-D elements of model '{model}' refer to node tags the model does not hold: {missing}")
    points = coords[order[pos_c]]
    cells = [(name, np.searchsorted(used, conn).astype(np.int64)) for name, _, conn in raw]
    element_tags = np.concatenate([t for _, t, _ in raw])
    skipped_nodes = np.zeros(used.size, dtype=bool)
    for nodes in skipped_raw:
        skipped_nodes[np.searchsorted(used, nodes)] = True
    return GmshCells(points=points, cells=cells, node_tags=used, element_tags=element_tags, model=model,
                     skipped=skipped, skipped_nodes=skipped_nodes)


def model_hexes() -> GmshCells:
    """The 8-node hexahedra of the current Gmsh model only (see :func:`model_cells`); raises NoHexahedraError
    when it has none."""
    mc = model_cells()
    H = mc.hexes
    if H.shape[0] == 0:
        raise NoHexahedraError(f"the Gmsh model '{mc.model}' holds no 8-node hexahedra (element type 5); it holds "
                               + ", ".join(f"{k} {t}" for t, k in mc.counts().items()))
    used, inverse = np.unique(H, return_inverse=True)
    return GmshCells(points=mc.points[used], cells=[("hexahedron", inverse.reshape(-1, 8).astype(np.int64))],
                     node_tags=mc.node_tags[used], element_tags=mc.hex_element_tags, model=mc.model,
                     skipped={}, skipped_nodes=np.zeros(used.size, dtype=bool))


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

    gmsh = gmsh_api()
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


def world_points(points, cells, pcoords) -> np.ndarray:
    """x(pcoords) of each cell: (K, 3) world points of (K, 3) parametric points (VTK's reference elements).

    ``cells`` is (K, 8) hexahedra (VTK order, parameter cube [0, 1]^3) or a list of (type, conn) blocks whose
    rows, concatenated, are the K cells the points belong to.
    """
    from hexsos_plugins.cells.elements import world_points as _world

    return _world(np.asarray(points, dtype=np.float64), _as_cells(cells), np.asarray(pcoords, dtype=np.float64))


def _as_cells(cells):
    if isinstance(cells, (list, tuple)):
        return [(t, np.asarray(c, dtype=np.int64)) for t, c in cells]
    return [("hexahedron", np.asarray(cells, dtype=np.int64).reshape(-1, 8))]


# --- views ---------------------------------------------------------------------------------------------

def hexsos_views() -> dict:
    """Tags of the hexsos views in the session, by key of :data:`VIEW_NAMES` (absent keys: no such view)."""
    gmsh = gmsh_api()
    found = {}
    for tag in gmsh.view.getTags():
        name = gmsh.option.getString(f"View[{gmsh.view.getIndex(tag)}].Name")
        for key, vname in VIEW_NAMES.items():
            if name == vname:
                found[key] = int(tag)
    return found


def remove_views(keys=None) -> None:
    """Remove the hexsos views (all of them, or those of the given keys of :data:`VIEW_NAMES`)."""
    gmsh = gmsh_api()
    for key, tag in hexsos_views().items():
        if keys is None or key in keys:
            gmsh.view.remove(tag)


def _new_view(key: str, existing: dict) -> int:
    """A fresh view for ``key``, taking over the tag of the previous one (so tags stay stable)."""
    gmsh = gmsh_api()
    old = existing.get(key)
    if old is not None:
        gmsh.view.remove(old)
        return int(gmsh.view.add(VIEW_NAMES[key], old))
    return int(gmsh.view.add(VIEW_NAMES[key]))


def _gmsh_data(result, element_tags, points, cells, model):
    info = result.extra.get("gmsh") if isinstance(getattr(result, "extra", None), dict) else None
    if element_tags is None:
        if info is None:
            raise GmshModelError("post_views: the result does not come from check_model; pass element_tags, "
                                 "points and cells")
        element_tags = info.element_tags
    if points is None or cells is None:
        if info is None:
            raise GmshModelError("post_views: pass points and cells (needed to place the argmin points)")
        points, cells = info.points, info.cells
    if model is None:
        model = info.model if info is not None else gmsh_api().model.getCurrent()
    element_tags = np.asarray(element_tags, dtype=np.uint64)
    if element_tags.shape != (len(result),):
        raise GmshModelError(f"post_views: expected {len(result)} element tags (one per checked element), "
                             f"found shape {element_tags.shape}")
    return element_tags, np.asarray(points, np.float64), _as_cells(cells), model


def _gmsh_cannot_show(model) -> bool:
    """Whether the Gmsh model holds element types Gmsh cannot post data on (prisms of order >= 3)."""
    from hexsos_plugins.cells.elements import ELEMENTS

    gmsh = gmsh_api()
    current = gmsh.model.getCurrent()
    try:
        if model and model != current:
            gmsh.model.setCurrent(model)
        types = set(int(t) for t in gmsh.model.mesh.getElementTypes(3))
    finally:
        if model and model != current:
            gmsh.model.setCurrent(current)
    return any(el.gmsh_type in types for el in ELEMENTS.values() if el.domain == "prism" and el.order >= 3)


def post_views(result, element_tags=None, points=None, cells=None, *, model: str | None = None) -> dict:
    """Post the results of a check as Gmsh views (replacing earlier hexsos views, keeping their tags).

    Parameters
    ----------
    result : hexsos_plugins.CheckResult
        From :func:`check_model` (which carries the tags and arrays), or from ``hexsos_plugins.check``
        on arrays that match the Gmsh model (then pass the three arrays below).
    element_tags : array_like of int, shape (M,), optional
        Gmsh tag of each element of the result.
    points : array_like, shape (N, 3), optional
    cells : (M, 8) hexahedra or a list of (type, conn) blocks, optional
        The arrays the result was computed on (to place the argmin points in world coordinates).
    model : str, optional, keyword-only
        The Gmsh model the element tags belong to. Default: the result's, else the current model.

    Returns
    -------
    dict
        View tags by key: ``"min_det"``, ``"status"`` (ElementData views over every checked element but prisms of
        order >= 3: Gmsh 4.15 posts no element data on a model holding them, and ``"element_views"`` then says
        so instead) and
        ``"argmin"`` (list data: one scalar point per invalid element at the world position of its argmin,
        valued by its min det J); ``"inside_only"`` and ``"mirrored"`` (the elements :func:`check_model` found
        written in the mirrored node order, blue; empty when none) beside the status view, and ``"key"``.
    """
    gmsh = gmsh_api()
    element_tags, points, cells, model = _gmsh_data(result, element_tags, points, cells, model)
    mirrored = getattr(result, "extra", {}).get("mirrored_element_tags")  # check_model's, else none
    mirrored = np.zeros(0, dtype=np.uint64) if mirrored is None else np.asarray(mirrored, dtype=np.uint64)
    existing = hexsos_views()
    views = {}

    # Gmsh 4.15 cannot post any model data (ElementData) on a model holding prisms of order >= 3 ("FaceClosureFull
    # not implemented for prisms of order 3", whatever elements the view covers): the two element views are then
    # left out (the key "element_views" says why); the argmin points below are list data and are posted
    if _gmsh_cannot_show(model):
        views["element_views"] = ("not posted: Gmsh cannot show element data on a model holding prisms of order "
                                  ">= 3; the argmin points are posted")
    else:
        views["min_det"] = tag = _new_view("min_det", existing)
        gmsh.view.addHomogeneousModelData(tag, 0, model, "ElementData", element_tags,
                                          np.ascontiguousarray(result.min_det, dtype=np.float64), numComponents=1)
        # a diverging scale centred on 0 would hide the magnitudes; keep Gmsh's default rainbow, but hidden:
        # the status view below shows the invalid elements, which the valid ones around them would cover
        gmsh.view.option.setNumber(tag, "Visible", 0)

        views["status"] = tag = _new_view("status", existing)
        gmsh.view.addHomogeneousModelData(tag, 0, model, "ElementData", element_tags,
                                          np.asarray(result.status, dtype=np.float64), numComponents=1)
        # draw only the elements that are not valid (status -1 or 0); valid ones (1) lie outside the range
        gmsh.view.option.setNumber(tag, "RangeType", 2)
        gmsh.view.option.setNumber(tag, "CustomMin", -1.0)
        gmsh.view.option.setNumber(tag, "CustomMax", 0.0)
        gmsh.view.option.setNumber(tag, "SaturateValues", 0)
        gmsh.view.option.setNumber(tag, "IntervalsType", 3)  # discrete colours
        gmsh.view.option.setNumber(tag, "NbIso", 2)
        gmsh.view.option.setString(tag, "Format", "%g")
        _colour_table(tag, [STATUS_RGB["undecided"], STATUS_RGB["invalid"]])

        inside = np.flatnonzero(np.asarray(result.invalid_inside_only, dtype=bool)) if len(result) else np.zeros(0, int)
        views["inside_only"] = tag = _new_view("inside_only", existing)
        if inside.size:
            gmsh.view.addHomogeneousModelData(tag, 0, model, "ElementData", element_tags[inside],
                                              np.zeros(inside.size), numComponents=1)
        else:
            gmsh.view.addListData(tag, "SS", 0, [])
        gmsh.view.option.setNumber(tag, "ShowScale", 0)
        gmsh.view.option.setNumber(tag, "Explode", 1.02)  # drawn just around the dark red of the status view
        _colour_table(tag, [STATUS_RGB["inside_only"]])

        # the elements written in the mirrored node order (check_model's finding), valid or not on their own
        views["mirrored"] = tag = _new_view("mirrored", existing)
        if len(mirrored):
            gmsh.view.addHomogeneousModelData(tag, 0, model, "ElementData", mirrored, np.zeros(len(mirrored)),
                                              numComponents=1)
        else:
            gmsh.view.addListData(tag, "SS", 0, [])
        gmsh.view.option.setNumber(tag, "ShowScale", 0)
        gmsh.view.option.setNumber(tag, "Explode", 1.04)
        _colour_table(tag, [STATUS_RGB["mirrored"]])

    # the key, at the top left of the graphics, instead of the status view's colour bar, whose
    # values (-1, 0) would say nothing: what each colour means, with the counts
    if "status" in views:
        gmsh.view.option.setNumber(views["status"], "ShowScale", 0)
    c = result.counts()
    lines = [f"hexsos: {c['invalid']} invalid (dark red), {c['invalid_inside_only']} of them inside only "
             f"(magenta), {c['undecided']} undecided (orange)",
             "white spheres: where det J is smallest" if c["invalid"] else "every element not drawn is valid"]
    if len(mirrored):
        lines.append(f"{len(mirrored)} written in the mirrored node order (blue)")
    views["key"] = tag = _new_view("key", existing)
    for k, line in enumerate(lines):
        gmsh.view.addListDataString(tag, [10, 14 + 18 * k], [line], ["FontSize", "14"])
    gmsh.view.option.setNumber(tag, "ShowScale", 0)

    bad = np.flatnonzero(np.asarray(result.status) == 0)
    views["argmin"] = tag = _new_view("argmin", existing)
    if bad.size:
        xyz = world_points(points, cells, np.asarray(result.argmin))[bad]
        data = np.column_stack([xyz, np.asarray(result.min_det)[bad]]).ravel()
        gmsh.view.addListData(tag, "SP", int(bad.size), data)
    else:
        gmsh.view.addListData(tag, "SP", 0, [])
    gmsh.view.option.setNumber(tag, "PointType", 1)  # spheres
    gmsh.view.option.setNumber(tag, "PointSize", 12)
    gmsh.view.option.setNumber(tag, "ShowScale", 0)
    # colormap 0 is all black; inverted, all white: white spheres stand out on the dark red invalid elements
    gmsh.view.option.setNumber(tag, "ColormapNumber", 0)
    gmsh.view.option.setNumber(tag, "ColormapInvert", 1)
    return views


def _colour_table(tag: int, colours) -> None:
    """Set the colour table of view ``tag`` (``View[i].ColorTable``, which the API sets through Gmsh's parser)."""
    import os
    import tempfile

    gmsh = gmsh_api()
    table = ", ".join("{%d, %d, %d}" % tuple(int(v) for v in rgb) for rgb in colours)
    fd, path = tempfile.mkstemp(suffix=".geo", prefix="hexsos-colours-")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(f"View[{gmsh.view.getIndex(tag)}].ColorTable = {{ {table} }};\n")
        gmsh.merge(path)
    finally:
        os.remove(path)


def post_displacement(node_tags, displacement, *, model: str | None = None) -> int:
    """Post a NodeData vector view ``"hexsos: displacement"`` (how far each node moved); returns its tag."""
    gmsh = gmsh_api()
    node_tags = np.asarray(node_tags, dtype=np.uint64)
    d = np.ascontiguousarray(displacement, dtype=np.float64).reshape(-1, 3)
    if d.shape[0] != node_tags.size:
        raise GmshModelError(f"post_displacement: expected {node_tags.size} displacement vectors, found {d.shape[0]}")
    tag = _new_view("displacement", hexsos_views())
    gmsh.view.addHomogeneousModelData(tag, 0, model or gmsh.model.getCurrent(), "NodeData", node_tags, d.ravel(),
                                      numComponents=3)
    gmsh.view.option.setNumber(tag, "Visible", 0)
    return tag


def _empty(tag: int) -> bool:
    """A view posted with no data (list data of no element)."""
    gmsh = gmsh_api()
    try:
        _, counts, _ = gmsh.view.getListData(tag)
    except Exception:  # a model-based view
        return False
    return sum(int(c) for c in counts) == 0


def write_views(path: str) -> list:
    """Write the hexsos views to ``path``; returns the files written.

    Any format ``gmsh.view.write`` takes. ``.pos`` (Gmsh's post-processing format) holds every view in one file.
    ``.msh`` holds the mesh once and the element / node data views (min det J, status, displacement); the
    argmin points are a list-based view, which Gmsh cannot put in a ``.msh`` beside a mesh (it would overwrite
    it), so they go to ``<path without .msh>-argmin.pos`` when there are any.
    """
    import os

    from hexsos_plugins.errors import MeshWriteError

    gmsh = gmsh_api()
    views = hexsos_views()
    if not views:
        raise GmshModelError("no hexsos views to write: run a check first")
    order = [k for k in VIEW_NAMES if k in views and k != "key"]  # the key is a picture's legend, not data
    stem, ext = os.path.splitext(path)
    written = []
    try:
        if ext.lower() == ".msh":
            save_mesh = gmsh.option.getNumber("PostProcessing.SaveMesh")
            try:
                model_based = [k for k in order if k != "argmin" and not (k in ("inside_only", "mirrored")
                                                                           and _empty(views[k]))]
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
    """Check every 3-D element of the current Gmsh model (all entities, every type :func:`model_cells` reads).

    Parameters
    ----------
    method, relaxation : keyword-only
        Passed to :func:`hexsos_plugins.check` (``"auto"`` / ``"sos"``; ``"quad2"`` / ``"paper"``).
    post_views : bool, keyword-only
        Post (or re-post) the views ``"hexsos: min det J"``, ``"hexsos: status"`` and the argmin points of
        the invalid elements. Default True.
    progress : callable(done, total), optional

    Returns
    -------
    hexsos_plugins.CheckResult
        Arrays in the order of ``result.extra["gmsh"].element_tags`` (a :class:`GmshCells`, which also holds
        the node tags, the dense arrays and the element types not checked); the posted view tags are in
        ``result.extra["gmsh_views"]``; ``result.by_type()`` the counts per type. Each element is judged as
        written; those written in the mirrored node order (:func:`hexsos_plugins.io.handedness.mirrored_cells`,
        every shared face read: a type all negatively oriented, or elements whose faces meet their neighbours'
        the wrong way round, which fold over them whatever their own verdicts) are named beside the verdicts:
        their tags in ``result.extra["mirrored_element_tags"]``, the sentence in ``result.extra["mirrored"]``
        ("" for none).

    Raises
    ------
    NoCellsError, GmshModelError, InvalidInputError (bad method / relaxation)
    """
    from hexsos_plugins.certify import check
    from hexsos_plugins.io.handedness import mirrored_cells
    from hexsos_plugins.io.mesh import Mesh

    hx = model_cells()
    result = check(hx.points, hx.cells, method=method, relaxation=relaxation, progress=progress,
                   jobs=0, quality=True)  # every core, as the command line; the scaled Jacobian too
    result.extra["gmsh"] = hx
    mirrored, said = mirrored_cells(Mesh.from_cells(hx.points, hx.cells), folded=True)
    result.extra["mirrored_element_tags"] = hx.element_tags[mirrored]
    result.extra["mirrored"] = said
    result.extra["gmsh_views"] = _post(result) if post_views else {}
    return result


def _post(result):
    return post_views(result)


def repair_model(*, repair_method: str = "optimize", boundary: str | None = None, min_sj=None,
                 rho: float = 200.0, margin=None, pin_boundary: bool = False, max_iter=None,
                 method: str = "auto", relaxation: str = "quad2", progress=None, post_views: bool = True,
                 pin_shared: bool | None = None, time_limit=None, callback=None, fix_orientation: bool = False):
    """Repair the current Gmsh model: move its nodes, re-check, re-post the views.

    Parameters
    ----------
    repair_method : {"optimize", "paper"}, keyword-only
        :func:`hexsos_plugins.repair`'s ``method``: untangle, raise the quality, certify (default), or the
        paper's Algorithms 1 and 2.
    boundary, min_sj, time_limit : keyword-only
        Passed to :func:`hexsos_plugins.repair` (default boundary: ``"slide"`` for optimize, ``"free"`` for
        paper; ``"fixed"`` with ``pin_boundary=True``).
    rho, margin, max_iter, relaxation, progress, callback : keyword-only
        Passed to :func:`hexsos_plugins.repair`; ``method`` is the kernel's (``"auto"`` / ``"sos"``, the
        paper's repair's u* finder).
    post_views : bool, keyword-only
        Re-post the check views of the repaired model and a ``"hexsos: displacement"`` NodeData view.
    pin_shared : bool, optional, keyword-only
        True: keep fixed every node the hexes share with other 3-D elements. Default (None): the repair decides
        -- linear tetrahedra, prisms and pyramids are repaired with the hexes by ``"optimize"`` (their nodes move
        only by steps that keep them valid), their nodes pinned by ``"paper"``; nodes of elements of other types
        (higher order) are pinned. Every 3-D element is checked: the repair succeeds only if all are valid.
    fix_orientation : bool, keyword-only
        Elements written in the mirrored node order (a type all negatively oriented, a region or element whose
        faces meet its neighbours' the wrong way round: it folds over them whatever its nodes' places;
        :func:`hexsos_plugins.io.handedness.right_handed`) are an error naming them (LeftHandedMeshError) unless
        this is True: then they are reversed in the model first (``gmsh.model.mesh.reverseElements``), their
        tags in ``extra["reversed_element_tags"]``. Default False: the model's elements are not changed unasked.

    Only nodes that moved are written back, with ``gmsh.model.mesh.setNode``. Parametric coordinates of nodes
    on CAD entities are left as they were.

    Returns
    -------
    RepairResult
        The kernel's result; ``extra`` also holds ``"model_check"`` (the check of every 3-D element read back
        from Gmsh), ``"gmsh"`` (the :class:`GmshCells` the repair started from), ``"moved_node_tags"``, and
        ``"other_cells"`` (the final check of the other 3-D elements).
    """
    from hexsos_plugins import repair

    gmsh = gmsh_api()
    hx, reversed_tags = _right_handed_model(model_cells(), fix_orientation)
    points, tags = hx.points, hx.node_tags
    cells = [(t, c) for t, c in hx.cells if t != "hexahedron"]
    pinned = hx.skipped_nodes.copy()
    from hexsos_plugins.meshrepair.curved import needs_curved

    # curved elements, or none but tetrahedra / prisms: repair() moves them on det J's Bernstein coefficients
    if hx.hexes.shape[0] == 0 and not (repair_method == "optimize" and needs_curved(hx.hexes, cells)):
        raise NoHexahedraError(f"the Gmsh model '{hx.model}' holds no 8-node hexahedra to repair; it holds "
                               + ", ".join(f"{k} {t}" for t, k in hx.counts().items()))
    if pin_shared:
        for _, conn in cells:
            pinned[conn.ravel()] = True
    # a kernel method as repair_method (the earlier signature) means the paper's repair
    res = repair(points, hx.hexes, cells=cells, method=repair_method, boundary=boundary, min_sj=min_sj,
                 rho=rho, margin=margin, pin_boundary=pin_boundary, max_iter=max_iter, kernel_method=method,
                 relaxation=relaxation, progress=progress, pinned=pinned if pinned.any() else None,
                 time_limit=time_limit, callback=callback,
                 jobs=1 if repair_method == "paper" else 0)  # paper: processes
    new = np.asarray(res.points, dtype=np.float64)
    moved = np.flatnonzero(np.any(new != points, axis=1))
    for i in moved:
        gmsh.model.mesh.setNode(int(tags[i]), new[i], [])
    after = check_model(method=method, relaxation=relaxation, post_views=post_views)
    if post_views:
        post_displacement(hx.node_tags, new - points, model=hx.model)
        after.extra["gmsh_views"] = hexsos_views()
    res.extra["model_check"] = after
    res.extra["gmsh"] = hx
    res.extra["moved_node_tags"] = tags[moved]
    res.extra["reversed_element_tags"] = reversed_tags
    return res


def _right_handed_model(hx, fix):
    """``hx`` (the model's :class:`GmshCells`) with the elements written in the mirrored node order reversed in
    the model when ``fix`` (re-read), else an error naming them; and the reversed elements' tags."""
    from hexsos_plugins.io.handedness import right_handed
    from hexsos_plugins.io.mesh import Mesh

    def mirrored(cells, fix):
        return right_handed(Mesh.from_cells(cells.points, cells.cells), fix, folded=True,
                            name=f"the Gmsh model '{cells.model}'",
                            hint="Set 'Fix orientation' in the hexsos panel's parameters to 1 (repair_model("
                                 "fix_orientation=True)) to reverse them, then repair")[2]

    flip = mirrored(hx, fix)
    if not flip.any():
        return hx, np.zeros(0, dtype=np.uint64)
    tags = hx.element_tags[flip]
    gmsh_api().model.mesh.reverseElements(tags.tolist())
    hx = model_cells()
    try:
        mirrored(hx, False)
    except HexsosError as e:  # Gmsh reversed them otherwise than their mirror image: say so, change nothing more
        raise GmshModelError(f"Gmsh's reverseElements left the model's elements mirrored: {e}") from None
    return hx, tags


#: The name of the view :func:`safe_step_model` posts (each element's proven safe fraction).
VIEW_SAFE_STEP = "hexsos: safe step"


def _node_displacement(hx, displacement, view, step):
    """(N, 3) displacement in the order of ``hx.node_tags``, from an array, a {node tag: vector} dict, or a
    NodeData vector view."""
    n = hx.node_tags.size
    if view is not None:
        gmsh = gmsh_api()
        kind, tags, data, _, ncomp = gmsh.view.getModelData(int(view), int(step))
        if kind != "NodeData" or ncomp not in (2, 3):
            raise GmshModelError(f"safe_step_model: expected view {view} to hold NodeData vectors, found {kind} "
                                 f"with {ncomp} components")
        displacement = {int(t): list(v) + [0.0] * (3 - ncomp) for t, v in zip(tags, data)}
    if isinstance(displacement, dict):
        D = np.zeros((n, 3))
        seen = np.zeros(n, dtype=bool)
        for t, v in displacement.items():
            i = int(np.searchsorted(hx.node_tags, np.uint64(t)))
            if i < n and int(hx.node_tags[i]) == int(t):
                D[i] = v
                seen[i] = True
        if not seen.all():
            missing = hx.node_tags[~seen][:5].tolist()
            raise GmshModelError(f"safe_step_model: expected a displacement for every node of the 3-D elements, "
                                 f"found none for {int((~seen).sum())} (tags {missing}...)")
        return D
    D = np.asarray(displacement, dtype=np.float64)
    if D.shape != (n, 3):
        raise GmshModelError(f"safe_step_model: expected a displacement array of shape ({n}, 3) in the order of "
                             f"the node tags of model_cells(), found shape {D.shape}")
    return D


def safe_step_model(displacement=None, *, view=None, step: int = 0, post_views: bool = True, rtol=None):
    """The certified largest fraction t* of a displacement of the current Gmsh model that keeps every 3-D element
    valid (:func:`hexsos_plugins.safe_step`).

    Parameters
    ----------
    displacement : (N, 3) array in the order of ``model_cells().node_tags``, or a dict {node tag: vector}
    view : int, optional, keyword-only
        Instead: the tag of a NodeData vector view (a solver's displacement), at time step ``step``.
    post_views : bool, keyword-only
        Post the ElementData view ``"hexsos: safe step"`` (each element's proven safe fraction). False: the
        model's t* alone (``per_cell=False``: faster; ``cell_t`` then holds lower bounds only).
    rtol : float, optional, keyword-only
        Passed to safe_step.

    Returns
    -------
    hexsos_plugins.SafeStepResult
        ``t`` the model's t*; ``extra["gmsh"]`` the :class:`GmshCells`, ``extra["witness_element_tag"]`` the Gmsh
        tag of the witness element (None without witness), ``extra["gmsh_view"]`` the posted view's tag.
    """
    from hexsos_plugins.certify.safe_step import safe_step

    if (displacement is None) == (view is None):
        raise GmshModelError("safe_step_model: pass either a displacement or view=TAG")
    hx = model_cells()
    D = _node_displacement(hx, displacement, view, step)
    kw = {} if rtol is None else {"rtol": rtol}
    result = safe_step(hx.points, hx.cells, D, jobs=0, per_cell=post_views, **kw)
    result.extra["gmsh"] = hx
    w = result.witness
    result.extra["witness_element_tag"] = int(hx.element_tags[w["cell"]]) if w is not None else None
    result.extra["gmsh_view"] = None
    if post_views:
        gmsh = gmsh_api()
        old = None
        for tag in gmsh.view.getTags():
            if gmsh.option.getString(f"View[{gmsh.view.getIndex(tag)}].Name") == VIEW_SAFE_STEP:
                old = int(tag)
                gmsh.view.remove(old)
        tag = int(gmsh.view.add(VIEW_SAFE_STEP, old) if old is not None else gmsh.view.add(VIEW_SAFE_STEP))
        gmsh.view.addHomogeneousModelData(tag, 0, hx.model, "ElementData", hx.element_tags,
                                          np.ascontiguousarray(result.cell_t, dtype=np.float64), numComponents=1)
        result.extra["gmsh_view"] = tag
    return result
