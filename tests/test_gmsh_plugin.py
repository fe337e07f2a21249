"""The Gmsh door: real Gmsh models in, results back through Gmsh views, ONELAB and the command line.

The meshes are built here with Gmsh (the demo ring: hexes inverted at corners and one hex valid at all 8
corners but invalid inside); the oracle is ``hexsos_plugins.check`` on the same arrays. What is tested is
the conversion (node and element tags, views, panel, CLI), not the kernel's math again.
"""

from __future__ import annotations

import os
import re
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest

gmsh = pytest.importorskip("gmsh")

from hexsos_plugins import NoHexahedraError, check  # noqa: E402
from hexsos_plugins.cells.elements import ELEMENTS  # noqa: E402
from hexsos_plugins.errors import InvalidInputError  # noqa: E402
from hexsos_plugins.examples import demo_mesh, gmsh_mesh, hexes_to_mesh, inside_invalid_hex  # noqa: E402
from xserver import virtual_display  # noqa: E402

import gmsh_plugin  # noqa: E402
from gmsh_plugin import model as gm  # noqa: E402
from gmsh_plugin import panel  # noqa: E402
from gmsh_plugin.__main__ import main  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# --- fixtures ------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def demo():
    """The demo ring (arrays), its kernel check (the oracle) and which hex is invalid inside only."""
    P, H, info = demo_mesh()
    ref = check(P, H)
    c = ref.counts()
    # the fixture must hold what the tests claim to test
    assert c["invalid"] >= 3 and c["invalid_inside_only"] == 1
    m = info["inside_only_hex"]
    assert ref.status[m] == 0 and ref.corner_min_det[m] > 0
    return P, H, info, ref


@pytest.fixture
def session():
    """A fresh Gmsh session (no config files, quiet)."""
    if gmsh.isInitialized():  # pragma: no cover - a test that failed half-way
        gmsh.finalize()
    gmsh.initialize(readConfigFiles=False)
    gmsh.option.setNumber("General.Terminal", 0)
    yield gmsh
    gmsh.finalize()


def _load_scrambled(P, H, *, seed=0, split=True):
    """Load arrays into a discrete Gmsh model with sparse, shuffled node tags, the hexes inserted in a
    shuffled order with sparse tags, in two volume entities. Returns node tag per point, element tag per hex."""
    rng = np.random.default_rng(seed)
    ntags = (1000 + 7 * rng.permutation(P.shape[0])).astype(np.uint64)  # sparse, not sorted
    etags = (50 + 3 * rng.permutation(H.shape[0])).astype(np.uint64)
    gmsh.model.add("scrambled")
    order = rng.permutation(P.shape[0])
    v1 = gmsh.model.addDiscreteEntity(3)
    gmsh.model.mesh.addNodes(3, v1, ntags[order], P[order].ravel())
    horder = rng.permutation(H.shape[0])
    parts = np.array_split(horder, 2) if split else [horder]
    for k, idx in enumerate(parts):
        vol = v1 if k == 0 else gmsh.model.addDiscreteEntity(3)
        gmsh.model.mesh.addElementsByType(vol, 5, etags[idx], ntags[H[idx]].ravel())
    return ntags, etags


def _index_of(tags_result, tags_ref):
    """Index into the reference order of each result tag."""
    lookup = {int(t): i for i, t in enumerate(tags_ref)}
    return np.array([lookup[int(t)] for t in tags_result])


def _world(P, H, uvw):
    """x(u, v, w) written out as nested linear interpolation (independent of the plugin's formula)."""
    out = []
    for hexa, (u, v, w) in zip(H, uvw):
        X = P[hexa]
        bottom = (1 - v) * ((1 - u) * X[0] + u * X[1]) + v * ((1 - u) * X[3] + u * X[2])
        top = (1 - v) * ((1 - u) * X[4] + u * X[5]) + v * ((1 - u) * X[7] + u * X[6])
        out.append((1 - w) * bottom + w * top)
    return np.array(out).reshape(-1, 3)


def _sorted_rows(a):
    a = np.round(np.asarray(a, dtype=np.float64), 9)
    return a[np.lexsort(a.T[::-1])]


# --- check_model ---------------------------------------------------------------------------------------

def test_check_model_matches_kernel_through_scrambled_tags(session, demo):
    P, H, info, ref = demo
    ntags, etags = _load_scrambled(P, H)
    result = gmsh_plugin.check_model()
    hx = result.extra["gmsh"]
    assert result.counts() == ref.counts()
    assert len(hx) == H.shape[0] and hx.model == "scrambled" and hx.skipped == {}
    # per hex, through the tags: same hex, same numbers
    idx = _index_of(hx.element_tags, etags)
    assert sorted(idx.tolist()) == list(range(H.shape[0]))
    np.testing.assert_array_equal(result.status, ref.status[idx])
    np.testing.assert_allclose(result.min_det, ref.min_det[idx], rtol=0, atol=1e-12)
    np.testing.assert_allclose(result.corner_min_det, ref.corner_min_det[idx], rtol=0, atol=1e-12)
    np.testing.assert_allclose(result.argmin, ref.argmin[idx], atol=1e-7)
    # the dense arrays are the original mesh, renamed
    back = _index_of(hx.node_tags, ntags)
    np.testing.assert_array_equal(hx.points, P[back])
    np.testing.assert_array_equal(back[hx.hexes], H[idx])
    m = int(np.flatnonzero(hx.element_tags == etags[info["inside_only_hex"]])[0])
    assert result.invalid_inside_only[m]


def test_renumbered_nodes_still_map_right(session, demo):
    P, H, _, ref = demo
    ntags, etags = gm.add_hex_mesh(P, H)
    assert ntags.tolist() == list(range(1, P.shape[0] + 1))
    new = (10**6 + 13 * np.random.default_rng(3).permutation(P.shape[0])).astype(np.uint64)
    gmsh.model.mesh.renumberNodes(ntags, new)
    assert np.asarray(gmsh.model.mesh.getNodes()[0]).min() >= 10**6
    result = gmsh_plugin.check_model(post_views=False)
    idx = _index_of(result.extra["gmsh"].element_tags, etags)
    np.testing.assert_array_equal(result.status, ref.status[idx])
    np.testing.assert_allclose(result.min_det, ref.min_det[idx], atol=1e-12)
    assert result.extra["gmsh_views"] == {} and gm.hexsos_views() == {}


def test_views_hold_the_results_per_element_tag(session, demo):
    P, H, info, ref = demo
    _, etags = _load_scrambled(P, H, seed=1)
    result = gmsh_plugin.check_model()
    views = result.extra["gmsh_views"]
    assert set(views) == {"min_det", "status", "argmin", "inside_only", "key", "mirrored"}
    assert gm.hexsos_views() == views
    names = {k: gmsh.option.getString(f"View[{gmsh.view.getIndex(t)}].Name") for k, t in views.items()}
    assert names == {"min_det": "hexsos: min det J", "status": "hexsos: status",
                     "argmin": "hexsos: where invalid elements fold", "inside_only": "hexsos: invalid inside only",
                     "key": "hexsos: key", "mirrored": "hexsos: written mirrored"}

    for key, expected in (("min_det", ref.min_det), ("status", ref.status.astype(float))):
        dtype, tags, data, _, ncomp = gmsh.view.getHomogeneousModelData(views[key], 0)
        assert dtype == "ElementData" and ncomp == 1 and len(tags) == H.shape[0]
        np.testing.assert_allclose(np.asarray(data), expected[_index_of(tags, etags)], atol=1e-12)

    # one point per invalid hex, at x(u*) of that hex, valued by its min det J
    types, counts, data = gmsh.view.getListData(views["argmin"])
    bad = np.flatnonzero(ref.status == 0)
    assert list(types) == ["SP"] and int(counts[0]) == bad.size
    got = np.asarray(data[0]).reshape(-1, 4)
    expected = np.column_stack([_world(P, H[bad], ref.argmin[bad]), ref.min_det[bad]])
    np.testing.assert_allclose(_sorted_rows(got), _sorted_rows(expected), atol=1e-6)
    # the inside-only hex folds away from its corners: its point is in the view and is none of its vertices
    m = info["inside_only_hex"]
    x = _world(P, H[[m]], ref.argmin[[m]])[0]
    assert np.min(np.linalg.norm(got[:, :3] - x, axis=1)) < 1e-6
    assert np.min(np.linalg.norm(P[H[m]] - x, axis=1)) > 1e-3


def test_checking_again_replaces_the_views(session, demo):
    P, H, _, _ = demo
    gm.add_hex_mesh(P, H)
    first = gmsh_plugin.check_model().extra["gmsh_views"]
    n_views = len(gmsh.view.getTags())
    second = gmsh_plugin.check_model().extra["gmsh_views"]
    assert second == first and len(gmsh.view.getTags()) == n_views
    gm.remove_views()
    assert gm.hexsos_views() == {} and len(gmsh.view.getTags()) == n_views - 6


def test_post_views_of_a_kernel_result(session):
    P, H = hexes_to_mesh(np.stack([inside_invalid_hex(), inside_invalid_hex() + [5.0, 0, 0]]))
    gm.add_hex_mesh(P, H, element_tags=[7, 3])
    ref = check(P, H)
    views = gmsh_plugin.post_views(ref, [7, 3], P, H)
    _, tags, data, _, _ = gmsh.view.getHomogeneousModelData(views["min_det"], 0)
    np.testing.assert_allclose(data, ref.min_det[_index_of(tags, [7, 3])])
    _, counts, _ = gmsh.view.getListData(views["argmin"])
    assert int(counts[0]) == 2
    with pytest.raises(gm.GmshModelError, match="element tags"):
        gmsh_plugin.post_views(ref, [7], P, H)
    with pytest.raises(gm.GmshModelError, match="does not come from check_model"):
        gmsh_plugin.post_views(ref)


def test_all_valid_mesh_posts_an_empty_argmin_view(session):
    P, H = gmsh_mesh("box", 2)
    gm.add_hex_mesh(P, H)
    result = gmsh_plugin.check_model()
    assert result.counts()["valid"] == 8
    _, counts, _ = gmsh.view.getListData(result.extra["gmsh_views"]["argmin"])
    assert sum(int(c) for c in counts) == 0


def test_other_volume_elements_are_checked_too(session):
    P, H = hexes_to_mesh(inside_invalid_hex())
    ntags, _ = gm.add_hex_mesh(P, H)
    vol = gmsh.model.addDiscreteEntity(3)
    gmsh.model.mesh.addNodes(3, vol, [100, 101], [0.0, 0.0, -1.0, 0.0, 0.0, 2.0])
    # two tets on the hex's nodes 0, 1, 2 and a new apex: one positively oriented (det of its edge vectors > 0,
    # VTK's convention), one mirrored
    X = {int(ntags[i]): P[i] for i in range(3)} | {100: np.array([0.0, 0.0, -1.0]), 101: np.array([0.0, 0.0, 2.0])}

    def oriented(tet, positive):
        d = np.linalg.det(np.array([X[tet[k]] - X[tet[0]] for k in (1, 2, 3)]))
        assert abs(d) > 1e-3
        return tet if (d > 0) == positive else [tet[1], tet[0], tet[2], tet[3]]

    good = oriented([int(ntags[0]), int(ntags[1]), int(ntags[2]), 100], True)
    bad = oriented([int(ntags[0]), int(ntags[1]), int(ntags[2]), 101], False)
    gmsh.model.mesh.addElementsByType(vol, 4, [], good + bad)
    result = gmsh_plugin.check_model()
    hx = result.extra["gmsh"]
    assert hx.counts() == {"hexahedron": 1, "tetra": 2} and len(result) == 3 and hx.points.shape == (10, 3)
    tet_tags = gmsh.model.mesh.getElementsByType(4)[0]
    status = dict(zip(hx.element_tags.tolist(), result.status.tolist()))
    names = dict(zip(hx.element_tags.tolist(), result.cell_type_names().tolist()))
    assert [status[int(t)] for t in tet_tags] == [1, 0] and [names[int(t)] for t in tet_tags] == ["tetra"] * 2
    assert result.counts()["invalid"] == 2 and result.counts()["invalid_inside_only"] == 1  # the hex
    # the views cover every element: the status of each element tag as posted
    _, tags, data, _, _ = gmsh.view.getHomogeneousModelData(result.extra["gmsh_views"]["status"], 0)
    posted = dict(zip(np.asarray(tags).tolist(), np.asarray(data).ravel().tolist()))
    assert posted == {k: float(v) for k, v in status.items()}
    # two fold points: the hex's (inside) and the mirrored tet's
    _, counts, _ = gmsh.view.getListData(result.extra["gmsh_views"]["argmin"])
    assert sum(int(c) for c in counts) == 2


def _box_order2(incomplete: bool):
    gmsh.model.add("order2")
    g = gmsh.model.geo
    p = [g.addPoint(*c) for c in [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]]
    lines = [g.addLine(p[i], p[(i + 1) % 4]) for i in range(4)]
    surf = g.addPlaneSurface([g.addCurveLoop(lines)])
    for c in lines:
        g.mesh.setTransfiniteCurve(c, 3)
    g.mesh.setTransfiniteSurface(surf)
    g.mesh.setRecombine(2, surf)
    g.extrude([(2, surf)], 0, 0, 1, numElements=[2], recombine=True)
    g.synchronize()
    gmsh.option.setNumber("Mesh.SecondOrderIncomplete", int(incomplete))
    gmsh.model.mesh.generate(3)
    gmsh.model.mesh.setOrder(2)


@pytest.mark.parametrize("incomplete,name", [(False, "hexahedron27"), (True, "hexahedron20")])
def test_second_order_hexes_are_checked_like_gmsh_reads_them(session, incomplete, name):
    """A Gmsh-made order-2 box, one interior edge node pushed through a face: every element checked in VTK's
    node order; the verdicts agree with the kernel on the same arrays and with Gmsh's minDetJac sign."""
    _box_order2(incomplete)
    tags, coords, _ = gmsh.model.mesh.getNodes()
    etype = 17 if incomplete else 12
    etags, enodes = gmsh.model.mesh.getElementsByType(etype)
    # push the mid-edge node of the first element's edge 0-1 far along the edge's normal: that element folds
    node = int(np.asarray(enodes).reshape(len(etags), -1)[0, 8])
    x = np.asarray(gmsh.model.mesh.getNode(node)[0])
    gmsh.model.mesh.setNode(node, list(x + [0.0, 0.0, 0.9]), [])
    result = gmsh_plugin.check_model()
    hx = result.extra["gmsh"]
    assert hx.counts() == {name: 8} and hx.skipped == {}
    again = check(hx.points, hx.cells)  # the same arrays through the library
    assert result.status.tolist() == again.status.tolist() and 1 <= (result.status == 0).sum() < 8
    q = np.asarray(gmsh.model.mesh.getElementQualities(list(map(int, hx.element_tags)), "minDetJac"))
    assert np.array_equal(np.sign(q) > 0, result.status == 1)
    assert f"8 elements (8 {name})" in hx.describe()


def test_types_without_an_exact_element_are_counted_not_checked(session):
    P, H = hexes_to_mesh(inside_invalid_hex())
    ntags, _ = gm.add_hex_mesh(P, H)
    vol = gmsh.model.addDiscreteEntity(3)
    base = [int(t) for t in ntags[:4]]
    # a tetrahedron of order 6 (84 nodes): hexsos checks orders 1 to 5
    t6 = gmsh.model.mesh.getElementType("Tetrahedron", 6)
    gmsh.model.mesh.addNodes(3, vol, list(range(200, 280)), np.random.default_rng(0).random(240).tolist())
    gmsh.model.mesh.addElementsByType(vol, t6, [], base + list(range(200, 280)))
    result = gmsh_plugin.check_model()
    hx = result.extra["gmsh"]
    assert len(result) == 1 and list(hx.skipped.values()) == [1] and "not checked" in hx.describe()
    assert hx.skipped_nodes.sum() == 84  # kept fixed by a repair


def test_no_hexahedra_and_no_session_are_typed_errors(session):
    gmsh.model.add("empty")
    with pytest.raises(NoHexahedraError, match="no 3-D elements"):
        gmsh_plugin.check_model()
    gmsh.finalize()
    try:
        with pytest.raises(gm.GmshModelError, match="not initialized"):
            gmsh_plugin.check_model()
    finally:
        gmsh.initialize(readConfigFiles=False)


def test_world_points_at_the_corners_are_the_vertices():
    P, H = hexes_to_mesh(inside_invalid_hex())
    from hexsos_plugins.cells.hexahedron import CORNERS

    np.testing.assert_allclose(gm.world_points(P, np.repeat(H, 8, axis=0), CORNERS), P[H[0]])
    np.testing.assert_allclose(gm.world_points(P, H, [[0.5, 0.5, 0.5]])[0], P.mean(axis=0))


def test_write_views(session, tmp_path):
    P, H = hexes_to_mesh(np.stack([inside_invalid_hex(), inside_invalid_hex() + [4.0, 0, 0]]))
    gm.add_hex_mesh(P, H)
    with pytest.raises(gm.GmshModelError, match="run a check first"):
        gm.write_views(str(tmp_path / "none.pos"))
    ref = gmsh_plugin.check_model()
    pos = tmp_path / "views.pos"
    assert gm.write_views(str(pos)) == [str(pos)]
    text = pos.read_text()
    for name in ("hexsos: min det J", "hexsos: status", "hexsos: where invalid elements fold"):
        assert f'View "{name}"' in text
    assert text.count("SP(") == 2
    # .msh: the mesh once with the element data; the argmin points beside it; Gmsh reads both back
    msh = tmp_path / "views.msh"
    files = gm.write_views(str(msh))
    assert files == [str(msh), str(tmp_path / "views-argmin.pos")]
    assert msh.read_text().count("$Nodes") == 1
    gmsh.model.add("reread")
    for f in files:
        gmsh.merge(f)
    names = {gmsh.option.getString(f"View[{gmsh.view.getIndex(t)}].Name"): t for t in gmsh.view.getTags()}
    assert sum(n == "hexsos: min det J" for n in names) == 1
    tag = [t for t in gmsh.view.getTags()
           if gmsh.option.getString(f"View[{gmsh.view.getIndex(t)}].Name") == "hexsos: min det J"][-1]
    _, _, data, _, _ = gmsh.view.getHomogeneousModelData(tag, 0)
    np.testing.assert_allclose(np.sort(data), np.sort(ref.min_det))


# --- the panel -----------------------------------------------------------------------------------------

def _results():
    num = {k: gmsh.onelab.getNumber(v)[0] for k, v in (("hexes", panel.R_HEXES), ("invalid", panel.R_INVALID),
                                                       ("inside_only", panel.R_INSIDE_ONLY),
                                                       ("undecided", panel.R_UNDECIDED),
                                                       ("min_det", panel.R_MIN_DET))}
    num["message"] = gmsh.onelab.getString(panel.R_MESSAGE)[0]
    return num


def _press(action):
    gmsh.onelab.setString("ONELAB/Action", [action])
    keep_going = panel.handle_action()
    assert gmsh.onelab.getString("ONELAB/Action") == [""]  # consumed, as in Gmsh's examples
    return keep_going


def test_panel_check_button(session, demo):
    P, H, _, ref = demo
    _load_scrambled(P, H, seed=2)
    panel.define_parameters()
    for name in (panel.P_METHOD, panel.P_RELAXATION, panel.P_RHO, panel.P_MARGIN, panel.P_PIN, panel.P_CHECK,
                 panel.P_REPAIR, panel.R_HEXES, panel.R_INVALID, panel.R_INSIDE_ONLY, panel.R_MIN_DET):
        assert gmsh.onelab.getNames(re.escape(name)) == [name]
    # the buttons are ONELAB actions carrying the values the handler reacts to
    import json

    for name, value in ((panel.P_CHECK, panel.ACTION_CHECK), (panel.P_REPAIR, panel.ACTION_REPAIR)):
        p = json.loads(gmsh.onelab.get(name))
        assert p["values"] == [value] and p["attributes"]["Macro"] == "Action"
    assert _results()["invalid"] == 0 and gm.hexsos_views() == {}
    assert _press(panel.ACTION_CHECK) is True
    c = ref.counts()
    r = _results()
    assert (r["hexes"], r["invalid"], r["inside_only"], r["undecided"]) == (
        c["hexes"], c["invalid"], c["invalid_inside_only"], c["undecided"])
    assert r["min_det"] == pytest.approx(float(ref.min_det.min()), abs=1e-12)
    assert f"{c['cells']} hexahedron ({c['invalid']} invalid, 1 inside only)" in r["message"]
    assert set(gm.hexsos_views()) == {"min_det", "status", "argmin", "inside_only", "key", "mirrored"}
    assert panel.last_result().counts() == c
    # unrelated actions are left alone and keep the loop going
    assert _press("check") is True and _results()["invalid"] == c["invalid"]


def test_panel_parameters_reach_the_kernel(session):
    P, H = hexes_to_mesh(np.stack([inside_invalid_hex(), inside_invalid_hex() + [4.0, 0, 0]]))
    gm.add_hex_mesh(P, H)
    panel.define_parameters()
    gmsh.onelab.setString(panel.P_METHOD, ["sos"])
    gmsh.onelab.setString(panel.P_RELAXATION, ["paper"])
    gmsh.onelab.setNumber(panel.P_RHO, [50.0])
    gmsh.onelab.setString(panel.P_MARGIN, ["2e-3"])
    gmsh.onelab.setNumber(panel.P_PIN, [1])
    gmsh.onelab.setNumber(panel.P_MAX_ITER, [7])
    assert panel.read_parameters() == {"method": "sos", "relaxation": "paper", "rho": 50.0, "margin": 2e-3,
                                       "pin_boundary": True, "max_iter": 7, "repair_method": "optimize",
                                       "boundary": "slide", "min_sj": None, "fix_orientation": False}
    gmsh.onelab.setString(panel.P_REPAIR_METHOD, ["paper"])
    gmsh.onelab.setString(panel.P_BOUNDARY, ["free"])
    gmsh.onelab.setString(panel.P_MIN_SJ, ["0.3"])
    p = panel.read_parameters()
    assert (p["repair_method"], p["boundary"], p["min_sj"]) == ("paper", "free", 0.3)
    gmsh.onelab.setString(panel.P_MIN_SJ, ["2"])
    with pytest.raises(InvalidInputError, match="scaled Jacobian"):
        panel.read_parameters()
    gmsh.onelab.setString(panel.P_MIN_SJ, ["auto"])
    _press(panel.ACTION_CHECK)
    res = panel.last_result()
    assert (res.method_requested, res.relaxation) == ("sos", "paper") and res.sos_solves >= 2
    assert _results()["inside_only"] == 2
    panel.define_parameters()  # reset
    assert panel.read_parameters()["margin"] is None and panel.read_parameters()["method"] == "auto"


def test_panel_errors_are_shown_not_raised(session):
    panel.define_parameters()
    gmsh.model.add("nothing")
    assert _press(panel.ACTION_CHECK) is True
    msg = _results()["message"]
    assert msg.startswith("error:") and "no 3-D elements" in msg
    assert panel.last_result() is None and isinstance(panel.last_error(), NoHexahedraError)
    P, H = hexes_to_mesh(inside_invalid_hex())
    gm.add_hex_mesh(P, H)
    gmsh.onelab.setString(panel.P_MARGIN, ["lots"])
    assert _press(panel.ACTION_REPAIR) is True
    assert "Repair margin" in _results()["message"]
    assert np.array_equal(gm.model_hexes().points, P)  # nothing moved
    assert _press("hexsos quit") is False


# --- repair --------------------------------------------------------------------------------------------

def _repairable():
    """A ring with an interior vertex pushed part-way through its neighbour (2 corner-invalid hexes) and a
    separate hex that is valid at its corners but invalid inside: 3 invalid hexes the repair fixes."""
    from hexsos_plugins.examples import OPPOSITE
    from hexsos_plugins.io.mesh import HexMesh

    P, H = gmsh_mesh("ring", 2)
    interior = np.flatnonzero(~HexMesh.from_arrays(P, H).boundary_vertices())
    v = int(interior[interior.size // 2])
    m = int(np.flatnonzero((H == v).any(axis=1))[0])
    k = int(np.flatnonzero(H[m] == v)[0])
    P[v] += 0.7 * (P[H[m][OPPOSITE[k]]] - P[v])
    X = 0.1 * inside_invalid_hex() + [3.0, 0.0, 0.0]
    P = np.vstack([P, X])
    H = np.vstack([H, P.shape[0] - 8 + np.arange(8)[None]])
    return P, H


def _write_repairable(directory) -> str:
    """:func:`_repairable` written by Gmsh as a .msh in ``directory``; returns its path."""
    path = str(directory / "repairable.msh")
    gmsh.initialize(readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gm.add_hex_mesh(*_repairable())
        gmsh.write(path)
    finally:
        gmsh.finalize()
    return path


def test_panel_repair_button_moves_the_nodes_in_the_model(session):
    P, H = _repairable()
    ref = check(P, H)
    assert ref.counts()["invalid"] == 3 and ref.counts()["invalid_inside_only"] == 1
    _load_scrambled(P, H, seed=4)
    panel.define_parameters()
    _press(panel.ACTION_CHECK)
    assert _results()["invalid"] == 3
    before = {int(t): c for t, c in zip(*_nodes())}
    _press(panel.ACTION_REPAIR)  # the default: boundary sliding
    res = panel.last_result()
    assert res.success, res.message
    r = _results()
    assert r["invalid"] == 0 and r["undecided"] == 0 and r["min_det"] > 0
    assert r["message"].startswith("repair succeeded") and "min scaled Jacobian" in r["message"]
    assert f"shortest / longest edge of a hex {res.stats['edge_ratio_before']:.3f} -> " \
           f"{res.stats['edge_ratio_after']:.3f}" in r["message"]
    assert res.stats["min_sj_after"] > 0
    assert gmsh.onelab.getNumber(panel.R_MIN_SJ)[0] == pytest.approx(res.stats["min_sj_after"])
    # the nodes moved in the Gmsh model, to the repaired coordinates, under their own tags
    after = {int(t): c for t, c in zip(*_nodes())}
    hx = res.extra["gmsh"]
    moved = {int(t) for t in res.extra["moved_node_tags"]}
    assert moved
    for i, t in enumerate(hx.node_tags):
        if int(t) in moved:
            np.testing.assert_array_equal(after[int(t)], res.points[i])
            assert not np.array_equal(after[int(t)], before[int(t)])
        else:
            np.testing.assert_array_equal(after[int(t)], before[int(t)])
    # an independent check of the model as Gmsh now holds it
    again = gmsh_plugin.check_model()
    assert again.counts()["invalid"] == 0 and again.counts()["valid"] == H.shape[0]
    dtype, tags, data, _, ncomp = gmsh.view.getHomogeneousModelData(gm.hexsos_views()["displacement"], 0)
    assert dtype == "NodeData" and ncomp == 3
    disp = np.asarray(data).reshape(-1, 3)[_index_of(hx.node_tags, tags)]
    np.testing.assert_allclose(disp, res.points - hx.points, atol=1e-12)


def test_panel_repair_names_its_stage_in_the_status_bar(session, monkeypatch):
    """With the GUI up, the repair writes the cells repaired, its stage and its seconds in Gmsh's status bar as
    it goes (and lets the window redraw); the line is cleared at the end. Without the GUI, nothing."""
    P, H = _repairable()
    _load_scrambled(P, H, seed=4)
    panel.define_parameters()
    shown, updates = [], []
    monkeypatch.setattr(gmsh.fltk, "setStatusMessage", lambda m, graphics=False: shown.append(m))
    monkeypatch.setattr(gmsh.fltk, "update", lambda: updates.append(len(shown)))
    _press(panel.ACTION_REPAIR)  # no GUI: no status line
    assert panel.last_result().success and shown == [] and updates == []
    _load_scrambled(P, H, seed=4)
    monkeypatch.setattr(panel, "gui_available", lambda: True)
    monkeypatch.setattr(gmsh.graphics, "draw", lambda: None)
    _press(panel.ACTION_REPAIR)
    res = panel.last_result()
    assert res.success, res.message
    assert shown[0] == "hexsos: repairing..." and shown[-1] == ""
    during = shown[1:-1]
    assert len(during) >= 2 and all(m.startswith("hexsos: repairing, ") for m in during), shown
    n = res.stats["invalid_before"]
    assert during[0] == f"hexsos: repairing, 0 of {n:,} cells repaired", during
    words = "untangling|smoothing|raising the quality|vertex steps|joint steps|standing quads back up"
    assert any(re.fullmatch(rf"hexsos: repairing, {n} of {n} cells repaired; ({words})[a-z ,]*, \d+ s", m)
               for m in during), during
    assert all(i >= 2 for i in updates[:len(during)])  # each status line drawn by an update


def _model_sides(a, b):
    """``face_sides`` of Gmsh hexes a and b (by element tag), read back from the model."""
    from folds import face_sides

    H = np.array([gmsh.model.mesh.getElement(tag)[1] for tag in (a, b)], dtype=np.int64)
    X = {int(n): gmsh.model.mesh.getNode(int(n))[0] for n in np.unique(H)}
    nodes = sorted(X)
    return face_sides(np.array([X[n] for n in nodes]), np.searchsorted(nodes, H), 0, 1)


def test_panel_repair_reverses_a_folded_element_only_when_asked(session):
    """The middle hex of a column is written mirrored and lies inside the lowest: every element is valid by its own
    node order. The panel's Repair names it and changes nothing; with Fix orientation it reverses that element in
    the model (Gmsh's reverseElements), repairs, and each shared face ends with its two hexes on opposite sides."""
    from hexsos_plugins.errors import LeftHandedMeshError
    from hexsos_plugins.examples import folded_column

    P, H = folded_column()
    ntags, etags = gm.add_hex_mesh(P, H)
    panel.define_parameters()
    _press(panel.ACTION_CHECK)
    r = _results()
    assert r["invalid"] == 0  # a fold is no element's own fault ...
    # ... but the check names it beside the verdicts, and the results turn pink
    assert panel.last_result().extra["mirrored_element_tags"].tolist() == [int(etags[1])]
    assert f"1 element (tags {int(etags[1])}) written in the mirrored node order" in r["message"]
    assert "'Fix orientation' = 1" in r["message"]
    views = gm.hexsos_views()
    _, shown, _, _, _ = gmsh.view.getHomogeneousModelData(views["mirrored"], 0)
    assert np.asarray(shown).tolist() == [int(etags[1])]
    assert any("1 written in the mirrored node order (blue)" in t for t in _strings(views["key"]))
    before = [gmsh.model.mesh.getElement(int(t))[1].tolist() for t in etags]
    assert _press(panel.ACTION_REPAIR) is True
    msg = _results()["message"]
    assert isinstance(panel.last_error(), LeftHandedMeshError)
    assert msg.startswith("error:") and "1 of the 3 hexahedron cells (cells 1)" in msg and "Fix orientation" in msg
    assert [gmsh.model.mesh.getElement(int(t))[1].tolist() for t in etags] == before  # nothing changed
    np.testing.assert_array_equal(gm.model_hexes().points, P)
    gmsh.onelab.setNumber(panel.P_FIX, [1])
    assert panel.read_parameters()["fix_orientation"] is True
    _press(panel.ACTION_REPAIR)
    res = panel.last_result()
    assert res.success, res.message
    assert res.extra["reversed_element_tags"].tolist() == [int(etags[1])]
    r = _results()
    assert r["invalid"] == 0 and "1 elements reversed first" in r["message"]
    after = [gmsh.model.mesh.getElement(int(t))[1].tolist() for t in etags]
    assert after[0] == before[0] and after[2] == before[2] and after[1] != before[1]
    assert sorted(after[1]) == sorted(before[1])  # the same nodes, the other way round
    for a, b in ((0, 1), (1, 2)):
        s, t = _model_sides(int(etags[a]), int(etags[b]))
        assert s * t < 0  # unfolded: each on its own side of the face it shares


def test_repair_model_refuses_or_reverses_a_left_handed_model(session):
    """Every hex written in the mirrored node order: negative everywhere, which no move of the nodes mends. Refused
    by name, or with fix_orientation reversed in Gmsh, found valid as it stands and left in place."""
    from hexsos_plugins.errors import LeftHandedMeshError
    from hexsos_plugins.examples import structured_grid

    P, H = structured_grid(2)
    _, etags = gm.add_hex_mesh(P, H)
    right = gmsh_plugin.check_model(post_views=False)
    assert right.extra["mirrored_element_tags"].size == 0 and right.extra["mirrored"] == ""
    H = H[:, [0, 3, 2, 1, 4, 7, 6, 5]]
    _, etags = gm.add_hex_mesh(P, H)
    left = gmsh_plugin.check_model(post_views=False)
    assert (left.status == 0).all()
    assert sorted(left.extra["mirrored_element_tags"].tolist()) == sorted(etags.tolist())
    assert "all 8 hexahedron cells are negatively oriented" in left.extra["mirrored"]
    with pytest.raises(LeftHandedMeshError, match="all 8 hexahedron cells are negatively oriented.*Fix orientation"):
        gmsh_plugin.repair_model()
    res = gmsh_plugin.repair_model(fix_orientation=True)
    assert res.success and sorted(res.extra["reversed_element_tags"].tolist()) == sorted(etags.tolist())
    assert (res.extra["model_check"].status == 1).all()
    np.testing.assert_allclose(gm.model_hexes().points, P, atol=1e-12)  # a perfect grid: nothing to move


def test_repair_model_pins_or_protects_nodes_shared_with_tetrahedra(session):
    P, H = hexes_to_mesh(inside_invalid_hex())
    ntags, _ = gm.add_hex_mesh(P, H)
    vol = gmsh.model.addDiscreteEntity(3)
    gmsh.model.mesh.addNodes(3, vol, [100], [0.0, 0.0, -1.0])
    shared = [int(ntags[0]), int(ntags[2]), int(ntags[1])]  # positively oriented with node 100 below
    gmsh.model.mesh.addElementsByType(vol, 4, [], shared + [100])
    tet_ok = lambda: ELEMENTS["tetra"].det(  # noqa: E731
        np.array([gmsh.model.mesh.getNode(t)[0] for t in shared + [100]])[None], ELEMENTS["tetra"].reference_nodes
    ).min() > 0
    assert tet_ok()
    # the paper's repair pins them
    res = gmsh_plugin.repair_model(repair_method="paper")
    assert res.success and res.extra["model_check"].counts()["invalid"] == 0
    for t in shared:
        np.testing.assert_array_equal(gmsh.model.mesh.getNode(t)[0], P[t - 1])
    assert not set(shared) & {int(t) for t in res.extra["moved_node_tags"]}
    # the default repair moves them with the tet in its energies, which stays valid; the result counts it
    for t in shared:
        gmsh.model.mesh.setNode(t, P[t - 1], [])
    res = gmsh_plugin.repair_model(boundary="free")
    assert res.success and res.stats["other_cells"] == 1 and res.stats["other_cells_invalid_after"] == 0
    assert res.extra["model_check"].counts()["invalid"] == 0 and tet_ok()


def test_repair_model_never_reports_success_with_inverted_prisms(session):
    from comparison.stress import hex_prism_block

    P, cells = hex_prism_block(4, amp=0.2, seed=1)
    H, W = cells[0][1], cells[1][1]
    ntags = np.arange(1, len(P) + 1, dtype=np.uint64)
    gmsh.model.add("mix")
    vol = gmsh.model.addDiscreteEntity(3)
    gmsh.model.mesh.addNodes(3, vol, ntags, P.ravel())
    gmsh.model.mesh.addElementsByType(vol, 5, [], ntags[H].ravel())
    gmsh.model.mesh.addElementsByType(vol, 6, [], ntags[W].ravel())  # Gmsh's prism order is VTK's
    inverted = lambda Q: ELEMENTS["wedge"].det(Q[W], ELEMENTS["wedge"].reference_nodes).min(axis=1) <= 0  # noqa
    assert inverted(P).sum() > 5
    res = gmsh_plugin.repair_model(repair_method="paper", max_iter=10)
    Q = np.array([gmsh.model.mesh.getNode(int(t))[0] for t in ntags])
    assert not res.success and "wedge" in res.message and inverted(Q).sum() >= 1
    assert res.stats["other_cells_invalid_after"] >= inverted(Q).sum()
    res = gmsh_plugin.repair_model()
    Q = np.array([gmsh.model.mesh.getNode(int(t))[0] for t in ntags])
    assert res.success and not inverted(Q).any() and res.extra["model_check"].counts()["invalid"] == 0


def _nodes():
    tags, coords, _ = gmsh.model.mesh.getNodes()
    return np.asarray(tags), np.asarray(coords).reshape(-1, 3)


# --- the command line ----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def demo_msh(tmp_path_factory, demo):
    P, H, _, _ = demo
    path = str(tmp_path_factory.mktemp("gmsh") / "demo.msh")
    own = not gmsh.isInitialized()
    if own:
        gmsh.initialize(readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        _load_scrambled(P, H, seed=5)
        gmsh.write(path)
        gmsh.model.remove()
    finally:
        if own:
            gmsh.finalize()
    return path


def _env(display=False):
    """The environment of a door's process: ``display`` False takes any display away, True keeps the caller's, a
    string (``":N"``) sets it."""
    env = dict(os.environ)
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    if isinstance(display, str):
        env["DISPLAY"] = display
        env.pop("WAYLAND_DISPLAY", None)
    elif not display:
        env.pop("DISPLAY", None)
        env.pop("WAYLAND_DISPLAY", None)
    return env


def _counts_in(text):
    out = {}
    for key, pat in (("hexes", r"^hexes\s+(\d+)"), ("invalid", r"^invalid\s+(\d+)"),
                     ("invalid_inside_only", r"of which (\d+) invalid inside only"), ("undecided", r"^undecided\s+(\d+)")):
        m = re.search(pat, text, re.M)
        out[key] = int(m.group(1)) if m else None
    return out


def test_cli_nopopup_prints_the_counts_and_writes_the_views(demo, demo_msh, tmp_path):
    _, _, _, ref = demo
    out = tmp_path / "views.pos"
    proc = subprocess.run([sys.executable, "-m", "gmsh_plugin", demo_msh, "-nopopup", "-o", str(out)],
                          capture_output=True, text=True, env=_env(display=True), cwd=str(tmp_path), timeout=120)
    assert proc.returncode == 1, proc.stderr
    c = ref.counts()
    assert _counts_in(proc.stdout) == {k: c[k] for k in ("hexes", "invalid", "invalid_inside_only", "undecided")}
    assert "invalid" in proc.stdout and "Gmsh element" in proc.stdout and "Traceback" not in proc.stderr
    text = out.read_text()
    assert 'View "hexsos: min det J"' in text and 'View "hexsos: status"' in text
    assert text.count("SP(") == c["invalid"]


def test_cli_all_valid_exits_0_in_process(tmp_path, capsys):
    path = str(tmp_path / "box.vtk")
    P, H = gmsh_mesh("box", 2)
    from hexsos_plugins.io import write
    from hexsos_plugins.io.mesh import HexMesh

    write(HexMesh.from_arrays(P, H), path)  # legacy VTK that Gmsh reads
    assert not gmsh.isInitialized()
    assert main([path, "-nopopup"]) == 0
    out = capsys.readouterr().out
    assert _counts_in(out)["hexes"] == 8 and _counts_in(out)["invalid"] == 0
    assert not gmsh.isInitialized()  # main finalizes the session it started


def test_cli_headless_without_display_and_repair(demo_msh, tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["--demo", "-o", str(tmp_path / "v.msh")]) == 1  # no display: headless, no -nopopup needed
    out = capsys.readouterr().out
    assert _counts_in(out)["invalid_inside_only"] == 1 and (tmp_path / "v.msh").exists()
    path = _write_repairable(tmp_path)
    assert main([path, "--auto-action", "repair"]) == 0
    out = capsys.readouterr().out
    assert "certified" in out and _counts_in(out)["invalid"] == 0


@pytest.mark.parametrize("ext", ["vtk", "mesh"])
def test_cli_reads_other_formats_gmsh_reads(demo, tmp_path, capsys, ext):
    P, H, _, ref = demo
    from hexsos_plugins.io import write
    from hexsos_plugins.io.mesh import HexMesh

    path = str(tmp_path / f"demo.{ext}")
    write(HexMesh.from_arrays(P, H), path)
    assert main([path, "-nopopup"]) == 1
    c = ref.counts()
    assert _counts_in(capsys.readouterr().out) == {k: c[k] for k in ("hexes", "invalid", "invalid_inside_only",
                                                                      "undecided")}


@pytest.mark.parametrize("content,what", [(None, "no such file"), ("", "no 3-D elements"),
                                          ("hello world\n", "Gmsh could not open it"), ("dir", "directory")])
def test_cli_bad_input_one_line_exit_2(tmp_path, content, what):
    path = tmp_path / "bad.msh"
    if content == "dir":
        path.mkdir()
    elif content is not None:
        path.write_text(content)
    proc = subprocess.run([sys.executable, "-m", "gmsh_plugin", str(path), "-nopopup"], capture_output=True,
                          text=True, env=_env(), cwd=str(tmp_path), timeout=120)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hexsos-gmsh: error:") and what in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr + proc.stdout


def test_cli_usage_errors(capsys):
    assert main(["x.msh", "--method", "nope", "-nopopup"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert main(["-nopopup"]) == 2
    assert "no MESH" in capsys.readouterr().err
    assert main(["--version"]) == 0


# --- the GUI under a virtual display -------------------------------------------------------------------

def _png_rgb(path):
    """Decode an 8-bit RGB/RGBA PNG (what Gmsh writes) without third-party packages."""
    with open(path, "rb") as f:
        data = f.read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, w = 8, b"", None
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos:pos + 4])
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, ctype = struct.unpack(">IIBB", body[:10])
            assert depth == 8 and ctype in (2, 6)
            ch = 3 if ctype == 2 else 4
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(h, 1 + w * ch)
    img = np.zeros((h, w * ch), dtype=np.int64)
    for y in range(h):
        f, line = raw[y, 0], raw[y, 1:].astype(np.int64)
        prev = img[y - 1] if y else np.zeros(w * ch, dtype=np.int64)
        if f == 0:
            cur = line
        elif f == 2:
            cur = (line + prev) % 256
        else:
            cur = np.zeros(w * ch, dtype=np.int64)
            for i in range(w * ch):
                a = cur[i - ch] if i >= ch else 0
                b, c = prev[i], (prev[i - ch] if i >= ch and y else 0)
                if f == 1:
                    pred = a
                elif f == 3:
                    pred = (a + b) // 2
                else:  # Paeth
                    p = a + b - c
                    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                    pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                cur[i] = (line[i] + pred) % 256
        img[y] = cur
    return img.reshape(h, w, ch)[..., :3]


def _screenshot_rgb(path):
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover - Pillow comes with matplotlib (extra "viz")
        return _png_rgb(str(path))
    return np.asarray(Image.open(path).convert("RGB")).astype(np.int64)


def _red_pixels(img):
    """Pixels of the status view's dark red (invalid hexes), above the colour scale at the bottom."""
    top = img[: int(0.8 * img.shape[0])]
    return int(((top[..., 0] > 90) & (top[..., 1] < 50) & (top[..., 2] < 50)).sum())


@pytest.fixture(scope="module")
def display():
    """A virtual X server of the tests' own (tests/xserver.py): the door's exit status is its own."""
    with virtual_display() as name:
        yield name


def _gui_run(mesh, tmp_path, action, display):
    shot = tmp_path / f"{action}.png"
    proc = subprocess.run([sys.executable, "-m", "gmsh_plugin", mesh, "--auto-action", action,
                           "--exit-after", "--screenshot", str(shot)], capture_output=True, text=True,
                          env=_env(display=display), cwd=str(tmp_path), timeout=120)
    assert "no display" not in proc.stderr, proc.stderr  # the GUI really ran
    assert "Traceback" not in proc.stderr, proc.stderr
    assert shot.exists() and shot.stat().st_size > 1000
    img = _screenshot_rgb(shot)
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 20  # not blank
    return proc, img


def test_gui_event_loop_under_xvfb(demo, demo_msh, tmp_path, display):
    _, _, _, ref = demo
    proc, img = _gui_run(demo_msh, tmp_path, "check", display)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert _counts_in(proc.stdout)["invalid"] == ref.counts()["invalid"]
    assert _red_pixels(img) > 200  # the invalid hexes are drawn


def test_gui_repair_button_under_xvfb(tmp_path, display):
    path = _write_repairable(tmp_path)
    proc, img = _gui_run(path, tmp_path, "repair", display)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "certified" in proc.stdout and _counts_in(proc.stdout)["invalid"] == 0
    assert _red_pixels(img) == 0  # no invalid hex left to draw


def test_png_decoder_reads_what_pil_writes(tmp_path):
    PIL = pytest.importorskip("PIL.Image")
    rng = np.random.default_rng(0)
    a = (rng.integers(0, 4, (20, 30, 3)) * 60).astype(np.uint8)
    PIL.fromarray(a).save(tmp_path / "x.png")
    np.testing.assert_array_equal(_png_rgb(str(tmp_path / "x.png")), a)


def test_public_names_resolve():
    for name in gmsh_plugin.__all__:
        assert getattr(gmsh_plugin, name) is not None
    for mod in (gm, panel):
        for name in mod.__all__:
            assert hasattr(mod, name), (mod.__name__, name)


# --- the safe step ----------------------------------------------------------------------------------------

def test_safe_step_model_from_a_view_and_from_arrays(session):
    """safe_step_model on a Gmsh model whose nodes are scrambled: a NodeData view (a solver's output) and an
    array give the kernel's answer on the same arrays; the witness maps to its Gmsh element; the view holds
    each element's safe fraction by tag."""
    from hexsos_plugins.examples import gmsh_mesh as ring
    from hexsos_plugins import safe_step

    P, H = ring("box", 3)
    D = np.zeros_like(P)
    centre = int(np.argmin(np.linalg.norm(P - P.mean(axis=0), axis=1)))
    D[centre] = [0.4, 0.3, 0.5]
    node_tags, elem_tags = _load_scrambled(P, H)
    hx = gm.model_cells()
    rows = np.searchsorted(node_tags[np.argsort(node_tags)], hx.node_tags)
    orig = np.argsort(node_tags)[rows]  # original point of each model row
    Dm = D[orig]
    view = gmsh.view.add("solver displacement")
    gmsh.view.addHomogeneousModelData(view, 0, gmsh.model.getCurrent(), "NodeData", hx.node_tags, Dm.ravel(),
                                      numComponents=3)
    r = gmsh_plugin.safe_step_model(view=view)
    expect = safe_step(P, H, D)
    assert 0 < r.t < 1 and r.t == expect.t
    a = gmsh_plugin.safe_step_model(Dm, post_views=False)
    assert a.t == r.t and a.extra["gmsh_view"] is None
    # the witness element is the one the kernel names, through the tags
    wtag = r.extra["witness_element_tag"]
    expected_tag = elem_tags[expect.witness["cell"]]
    assert wtag == expected_tag
    # the posted view holds each element's fraction by element tag
    kind, tags, data, _, _ = gmsh.view.getModelData(r.extra["gmsh_view"], 0)
    got = dict(zip(np.asarray(tags).tolist(), np.asarray(data).ravel().tolist()))
    assert got[int(expected_tag)] == r.t
    assert min(got.values()) == r.t and max(got.values()) == 1.0
    with pytest.raises(gm.GmshModelError, match="shape"):
        gmsh_plugin.safe_step_model(np.zeros((3, 3)))


# --- what a user of the Gmsh door sees (issue: screenshot, order-3 message, status key, panel labels) -----------

def test_screenshot_without_auto_action_is_the_opened_model_and_ends_by_itself(tmp_path, display):
    import signal

    shot = tmp_path / "opened.png"
    proc = subprocess.Popen([sys.executable, "-m", "gmsh_plugin", "--demo", "--screenshot",
                             str(shot)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env(display=display), cwd=str(tmp_path), start_new_session=True)
    try:
        out, err = proc.communicate(timeout=90)
    except subprocess.TimeoutExpired:  # waits for an action that never comes: end it
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail("hexsos gmsh --screenshot without --auto-action did not end by itself within 90 s")
    proc = subprocess.CompletedProcess(proc.args, proc.returncode, out, err)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "no display" not in proc.stderr and f"wrote {shot}" in proc.stdout
    img = _screenshot_rgb(shot)
    mesh = np.abs(img - img[-1, -1]).max(axis=2) > 40  # Gmsh's mesh lines on its light background
    assert mesh.mean() > 0.02 and _red_pixels(img) == 0  # the model as opened: nothing checked, nothing red


def test_an_order_6_mesh_is_named_as_such_not_sent_back_to_meshing(tmp_path):
    path = tmp_path / "order6.msh"
    gmsh.initialize(readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("o6")
        gmsh.model.occ.addBox(0, 0, 0, 1, 1, 1)
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.MeshSizeMax", 0.7)
        gmsh.model.mesh.generate(3)
        gmsh.model.mesh.setOrder(6)
        assert len(gmsh.model.mesh.getElementTypes(3)) == 1
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    proc = subprocess.run([sys.executable, "-m", "gmsh_plugin", str(path), "-nopopup"], capture_output=True,
                          text=True, env=_env(), cwd=str(tmp_path), timeout=120)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    (line,) = proc.stderr.strip().splitlines()
    assert "orders 1 to 5" in line and "Tetrahedron 84" in line and "mesh it in 3-D first" not in line, line


def test_status_views_colour_inside_only_apart_and_carry_a_key(demo):
    P, H, info, ref = demo
    c = ref.counts()
    gmsh.initialize(readConfigFiles=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        _, etags = gm.add_hex_mesh(P, H)
        result = gmsh_plugin.check_model()
        views = result.extra["gmsh_views"]
        assert {"status", "inside_only", "key"} <= set(views)
        _, tags, data, _, _ = gmsh.view.getHomogeneousModelData(views["inside_only"], 0)
        assert np.asarray(tags).tolist() == [int(etags[info["inside_only_hex"]])]
        assert gmsh.view.option.getNumber(views["status"], "ShowScale") == 0  # no bare -1..0 bar
        # the key names the colours with the counts
        (text,) = [s for s in _strings(views["key"]) if "invalid" in s]
        assert f"{c['invalid']} invalid (dark red)" in text and f"{c['invalid_inside_only']} of them inside only" \
            in text and f"{c['undecided']} undecided" in text
        assert not any("mirrored" in t for t in _strings(views["key"]))  # none written mirrored: no such line
        # re-posting replaces the views instead of piling them up
        gmsh_plugin.check_model()
        assert len(gmsh.view.getTags()) == len(gm.hexsos_views()) == 6
    finally:
        gmsh.finalize()


def _strings(tag):
    _, strings, _ = gmsh.view.getListDataStrings(tag, 2)
    return list(strings)


def _magenta_pixels(img):
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return int(((r > 150) & (b > 150) & (g < 90)).sum())


def test_gui_picture_shows_the_inside_only_hex_in_magenta_and_the_key(demo_msh, tmp_path, display):
    proc, img = _gui_run(demo_msh, tmp_path, "check", display)
    assert _magenta_pixels(img) > 30 and _red_pixels(img) > 200, (_magenta_pixels(img), _red_pixels(img))
    top = np.abs(img[:40, :300] - img[60, 5]).max(axis=2) > 100  # the key's text at the top left
    assert top.sum() > 200


PANEL_SCRIPT = r'''
import os, sys
import gmsh
from PIL import ImageGrab
from gmsh_plugin import panel, __main__ as door
gmsh.initialize(readConfigFiles=False)
gmsh.option.setNumber("General.Terminal", 0)
door._open(gmsh, door.build_parser().parse_args(["--demo"]))
panel.widen_menu()
gmsh.fltk.initialize()
panel.define_parameters()
gmsh.fltk.openTreeItem("hexsos")
panel.handle_action(panel.ACTION_CHECK)
for _ in range(20):
    gmsh.fltk.wait(0.05)
ImageGrab.grab(xdisplay=os.environ["DISPLAY"]).save(sys.argv[1])
gmsh.finalize()
'''


def _labels_cut(png):
    """Rows of the tree (left pane) where text reaches its right edge, the scrollbar: a label cut off."""
    img = _screenshot_rgb(png)
    white = (img == 255).all(axis=2)
    half = img.shape[1] // 2
    edge = white[:, :half] & ~white[:, 1:half + 1]
    xw = int(np.argmax(edge.sum(axis=0)))  # the last white column of the tree
    bar = img[:, xw + 4]
    grey = (bar[:, 0] == bar[:, 1]) & (bar[:, 1] == bar[:, 2]) & (bar[:, 0] > 100) & (bar[:, 0] < 230)
    rows = np.flatnonzero(white[:, xw] & grey)
    dark = img.max(axis=2) < 140
    assert rows.size > 200, "the tree was not found in the screenshot"
    return [int(y) for y in range(rows.min(), rows.max() + 1) if grey[y] and dark[y, xw - 3: xw + 1].any()]


def test_panel_labels_fit_and_the_method_comes_before_the_papers_parameters(tmp_path):
    pytest.importorskip("PIL.ImageGrab")
    script, shot = tmp_path / "panel.py", tmp_path / "panel.png"
    script.write_text(PANEL_SCRIPT)
    with virtual_display("1600x1000x24") as wide:
        proc = subprocess.run([sys.executable, str(script), str(shot)], capture_output=True, text=True,
                              env=_env(display=wide), cwd=str(tmp_path), timeout=90)
    assert proc.returncode == 0 and shot.exists(), proc.stderr
    assert _labels_cut(shot) == []
    # ONELAB sorts by name: every repair's parameters, then the paper's own (rho, margin)
    order = sorted([panel.P_METHOD, panel.P_RELAXATION, panel.P_REPAIR_METHOD, panel.P_BOUNDARY, panel.P_MIN_SJ,
                    panel.P_PIN, panel.P_MAX_ITER, panel.P_FIX, panel.P_RHO, panel.P_MARGIN])
    assert order[0] == panel.P_METHOD and order[2] == panel.P_REPAIR_METHOD and order[-2:] == [panel.P_RHO,
                                                                                              panel.P_MARGIN]


def test_a_model_read_from_msh2_with_every_element_twice_is_checked_and_repaired_once(session, tmp_path):
    """A box in two physical volumes saved as MSH 2 has every tet written twice, and Gmsh opens it so: the panel's
    check names the copies in its summary (each valid, as its original), and its repair certifies every element
    (it refused the model before: "no repair makes them a mesh")."""
    from conftest import write_box_in_two_groups

    write_box_in_two_groups(gmsh, tmp_path / "two.msh")
    gmsh.clear()
    gmsh.open(str(tmp_path / "two.msh"))
    n = sum(len(t) for t in gmsh.model.mesh.getElements(3)[1])
    r = gm.check_model(post_views=False)
    assert len(r) == n and (r.status == 1).all() and f"repeated   {n // 2} cells name the same points" in r.summary()
    res = gm.repair_model()
    assert res.success and len(res.check) == n and res.stats["repeated_cells"] == n // 2
