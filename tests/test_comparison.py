"""The comparison harness: every experiment at tiny sizes, its report, pictures and summary, and sane figures."""

import json

import numpy as np
import pytest

pytest.importorskip("matplotlib")
pytest.importorskip("gmsh")
pytest.importorskip("vtkmodules")

from comparison import EXPERIMENTS  # noqa: E402
from comparison import common as C  # noqa: E402
from comparison import argmin_locations, figures_1_2, sampling  # noqa: E402
from comparison.__main__ import main  # noqa: E402
from hexsos_plugins import check  # noqa: E402
from hexsos_plugins.examples import hexes_to_mesh, inside_invalid_hex, random_hexes, unit_cube  # noqa: E402

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """``python -m comparison --tiny`` with a generated mesh and an unreadable file in --meshes."""
    import meshio

    from hexsos_plugins.examples import demo_mesh
    from hexsos_plugins.io import write

    root = tmp_path_factory.mktemp("comparison")
    meshes = root / "meshes"
    meshes.mkdir()
    P, H, _ = demo_mesh(3)
    write(meshio.Mesh(P, [("hexahedron", H)]), meshes / "demo3.vtu")
    (meshes / "garbage.vtk").write_text("this is not a mesh\n")
    out = root / "out"
    rc = main(["--tiny", "--out", str(out), "--jobs", "1", "--meshes", str(meshes)])
    summary = json.loads((out / "summary.json").read_text())
    return rc, out, summary, (P, H)


def test_report_pictures_and_summary_keys(tiny_run):
    rc, out, s, _ = tiny_run
    assert rc == 0 and s["errors"] == {}
    report = (out / "report.md").read_text()
    for name, _, _ in EXPERIMENTS:
        assert name in s and name in s["experiments"], name
    for title in ("1. Exactness", "2. Against Gmsh", "3. Against VTK", "4. Exact recovery", "5. Where the minimum",
                  "6. Figures 1 and 2", "7. Meshes", "8. Every cell type"):
        assert f"## {title}" in report
    # every table is preceded by its sentence: the line before a header row is blank, the one before it text
    lines = report.splitlines()
    headers = [i for i, ln in enumerate(lines) if ln.startswith("| ") and lines[i + 1].startswith("|---")]
    assert len(headers) >= 12
    for i in headers:
        assert lines[i - 1] == "" and lines[i - 2].strip() and not lines[i - 2].startswith("|")
    expected = {"fig8_left_sampling.png", "fig8_right_gmsh.png", "fig5_recovery.png", "fig10_argmin.png",
                "fig1_twist.png", "fig2_ball.png", "fig9_meshes.png"}
    assert expected <= set(s["figures"])
    for f in s["figures"]:
        data = (out / f).read_bytes()
        assert data[:8] == PNG and len(data) > 5000, f
        assert f"]({f})" in report
    for k in ("hexsos", "numpy", "scipy", "clarabel", "gmsh", "vtk"):
        assert s["versions"][k], k
    assert "seed" in report and "random_hexes(sigma=0.3, seed=1)" in report
    assert {"hexes", "max_abs_diff"} <= set(s["sampling"])
    assert {"hexes", "sign_disagreements", "max_gap", "throughput_ratio"} <= set(s["gmsh"])


def test_cell_types_agree_with_gmsh_and_vtk_sampling(tiny_run):
    x = tiny_run[2]["cell_types"]
    assert {s["type"] for s in x["sets"]} == {"tetra", "tetra10", "pyramid", "pyramid13", "pyramid14", "wedge",
                                              "wedge15", "wedge18", "hexahedron", "hexahedron20", "hexahedron27"}
    assert x["sign_disagreements"] == 0 and x["gmsh_above_ours"] == 0  # Gmsh's certified bound never above our min
    # quadratic pyramids: where Gmsh's bound sits above our minimum, Gmsh's own det J at our argmin is below it
    q = x["quadratic_pyramids"]
    assert q["gmsh_above_ours"] > 0 and q["gmsh_det_below_its_bound"] == q["gmsh_above_ours"]
    assert x["sampled_below_lower"] == 0 and x["valid_but_sampled_nonpositive"] == 0  # sampling never refutes us
    assert x["max_bracket"] <= 1e-8
    assert sum(s["invalid"] for s in x["sets"]) > 0 and sum(s["inside_only"] for s in x["sets"]) > 0
    # the curved cells of order 3: sampling (VTK's Lagrange cells; pyramids Gmsh's) never below our lower bound,
    # every cell decided, Gmsh's decisive signs agree on tetrahedra and hexahedra
    c = x["curved"]
    assert {s["type"] for s in c["sets"]} == {"tetra20", "hexahedron64", "wedge40", "pyramid30"}
    assert c["sampled_below_lower"] == 0 and c["undecided"] == 0
    assert all(s["sign_disagreements"] == 0 for s in c["sets"] if s["type"] in ("tetra20", "hexahedron64"))


def test_sampling_is_sane(tiny_run):
    x = tiny_run[2]["sampling"]
    assert x["hexes"] == sampling.SIZES["tiny"]["hexes"]
    assert x["dense_below_lower_bound"] == 0  # a sampled value below a certified lower bound: a broken proof
    assert x["ours_above_dense"] == 0  # our minimum above a sampled value: not the minimum
    assert x["max_abs_diff_closed_grid"] < 1e-6
    assert 0 < x["max_abs_diff"] < 2e-3  # the centre recipe misses boundary minima by ~|grad| * 5e-5
    assert x["max_interp_err"] < 1e-12
    assert set(x["methods"]) == {"auto", "sos, quad2", "sos, paper"}


def test_gmsh_and_vtk_are_sane(tiny_run):
    g, v = tiny_run[2]["gmsh"], tiny_run[2]["vtk"]
    assert g["hexes"] == 2 * 500 + 1
    assert g["sign_disagreements"] == 0
    assert g["gmsh_above_ours"] == 0  # Gmsh's certified bound never above our exact minimum
    assert 0 <= g["max_gap"] <= 1.001e-3  # Gmsh refines to 1e-3 of max|det J| (<= our scale)
    assert g["throughput_ratio"] > 0
    assert v["misses_inside_invalid_hex"] is True
    assert v["sets"]["inside_invalid_hex()"]["vtk_jacobian"] > 0 > v["sets"]["inside_invalid_hex()"]["true_min"]
    assert v["false_alarms"] == 0
    assert 0 < v["missed"] < v["invalid"]


def test_recovery_argmin_and_figures_are_sane(tiny_run):
    s = tiny_run[2]
    rec = s["recovery"]
    assert set(rec["degrees"]) == {"4", "6"}
    for d in rec["degrees"].values():
        assert d["solved"] == d["hexes"] and d["max"] < 1e-3 and d["max_rel_value_err"] < 1e-6
    assert rec["whole_sample"]["paper"]["solved"] == rec["whole_sample"]["paper"]["hexes"]

    loc = s["argmin_locations"]
    assert set(loc) == {"0.3", "0.5", "1.0"}
    for counts in loc.values():
        assert set(counts) == set(argmin_locations.CATEGORIES)
        assert sum(counts.values()) == argmin_locations.SIZES["tiny"]["hexes"]
    for st in s["knupp"]["per_sigma"].values():
        assert st["interior_certified"] <= st["invalid"] and st["knupp_undetermined"] == 0
    assert loc["0.3"]["interior"] == 0  # as the paper

    f = s["figures_1_2"]
    assert f["figure1"]["corner_invalid"] == 0 and 140 <= f["figure1"]["first_invalid_deg"] <= 150
    assert f["figure1"]["shear_0.6_first_invalid_deg"] == 180.0
    b = f["figure2"]
    assert b["start_status"] == 1 and b["inside_only"] > 0 and b["corner_invalid"] > 0
    assert b["valid"] + b["corner_invalid"] + b["inside_only"] + b["undecided"] == b["positions"]
    assert f["unit_cube_moves"]["inside_only"] == 0 < f["unit_cube_moves"]["corner_invalid"]


def test_meshes_counts_and_repair(tiny_run):
    _, _, s, (P, H) = tiny_run
    m = {x["mesh"]: x for x in s["meshes"]["meshes"]}
    r = check(P, H)
    assert m["demo3"]["hexes"] == len(H) and m["demo3"]["invalid"] == int((r.status == 0).sum()) > 0
    assert m["demo3"]["invalid_inside_only"] == 1 and m["demo3"]["gmsh_sign_disagreements"] == 0
    assert m["demo3"]["vtk_missed"] >= 1
    assert any(p.endswith("garbage.vtk") for p in s["meshes"]["skipped"])
    rep = {x["mesh"]: x for x in s["meshes"]["repair"]}
    assert rep["demo3"]["invalid_before"] == m["demo3"]["invalid"]
    assert rep["demo3"]["certified"] is True and rep["demo3"]["invalid_after"] == 0


def test_dense_sampling_finds_known_minima():
    X = np.stack([inside_invalid_hex(), unit_cube()])
    v, p, err = sampling.dense_min(X, recipe="closed")
    assert v[0] == pytest.approx(-0.199276, abs=1e-6) and np.allclose(p[0], [1, 0, 0.468061], atol=2e-3)
    assert v[1] == pytest.approx(1.0, abs=1e-12) and err.max() < 1e-12
    vp, pp, _ = sampling.dense_min(X, recipe="paper")
    assert -0.199276 < vp[0] < -0.199276 + 1e-3  # centres only: above the true minimum, within the grid's reach
    assert np.all((pp > 0) & (pp < 1))
    with pytest.raises(ValueError):
        sampling.dense_min(X, recipe="bogus")


def test_sanity_counts_catch_a_wrong_lower_bound():
    # the sanity check of experiment 1 must be able to fail: raise the lower bounds above the truth
    X = random_hexes(6, sigma=0.3, seed=5)
    r = check(*hexes_to_mesh(X))
    dense = sampling.dense_both(X)
    assert sampling.sanity_counts(r, dense) == (0, 0)
    r.lower_bound = r.min_det + 1e-3 * r.scale
    r.min_det = r.min_det + 1e-3 * r.scale
    below, above = sampling.sanity_counts(r, dense)
    assert below == 6 and above == 6


def test_classify_and_face_brackets():
    pts = np.array([[0, 1, 0], [0.5, 0, 1], [0.3, 0.4, 1.0 - 5e-5], [0.5, 0.5, 0.5], [2e-4, 0.5, 0.5]])
    assert argmin_locations.classify(pts).tolist() == [0, 1, 2, 3, 3]
    lo = argmin_locations.face_lower_bounds(np.stack([unit_cube(), inside_invalid_hex()]))
    assert np.allclose(lo[0], 1.0, atol=1e-9)
    assert lo[1].min() <= -0.199276 + 1e-6  # the fixture's minimum lies on an edge, so on two faces


def test_standalone_module_and_parallel_chunks(tmp_path):
    assert figures_1_2.main(["--tiny", "--out", str(tmp_path), "--jobs", "1"]) == 0
    assert json.loads((tmp_path / "figures_1_2.json").read_text())["figures_1_2"]["figure2"]["positions"] > 0
    assert (tmp_path / "figures_1_2.md").read_text().startswith("## 6.")
    X = random_hexes(40, sigma=0.5, seed=9)
    a, b = C.check_hexes(X, 1), C.check_hexes(X, 2)
    assert np.array_equal(a.min_det, b.min_det) and np.array_equal(a.status, b.status)


def test_unknown_experiment_is_a_usage_error(tmp_path):
    with pytest.raises(SystemExit) as e:
        main(["--tiny", "--out", str(tmp_path), "--only", "nonsense"])
    assert e.value.code == 2
