"""``hexsos check`` and ``hexsos demo`` end to end (``main(argv)`` returns the exit code)."""

import hashlib
import json
import os
import subprocess
import sys

import meshio
import numpy as np
import pytest

import hexsos_plugins as hs
from hexsos_plugins import cli
from hexsos_plugins.examples import demo_mesh, inside_invalid_hex, structured_grid
from hexsos_plugins.io import read_meshio


def _fingerprint(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest(), os.stat(path).st_mtime_ns


@pytest.fixture(scope="module")
def demo_arrays():
    return demo_mesh()


@pytest.fixture
def demo_file(tmp_path, demo_arrays):
    P, H, _ = demo_arrays
    # a mixed mesh: the hexes, a quad block, point data, cell data and field data
    quads = H[:5, :4]
    mesh = meshio.Mesh(P, [("hexahedron", H), ("quad", quads)],
                       point_data={"temperature": np.arange(len(P), dtype=float)},
                       cell_data={"region": [np.full(len(H), 7), np.full(5, 3)]},
                       field_data={"solid": np.array([7, 3])})
    path = tmp_path / "demo.vtu"
    meshio.write(path, mesh)
    return path


def test_demo_writes_the_annotated_mesh(tmp_path, capsys, demo_arrays):
    out = tmp_path / "d.vtu"
    assert cli.main(["demo", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "invalid inside only" in text and "what corner checks miss" in text
    png = tmp_path / "d.png"  # the picture beside OUT
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20000 and f"wrote {png}" in text
    m = meshio.read(out)
    P, H, info = demo_arrays
    ref = hs.check(P, H)
    status = m.cell_data["hexsos_status"][0]
    assert np.array_equal(status, ref.status)
    assert (status == 0).sum() >= 3 and ref.invalid_inside_only.sum() >= 1
    assert status[info["inside_only_hex"]] == 0 and m.cell_data["hexsos_corner_min_det"][0][info["inside_only_hex"]] > 0
    assert m.cell_data["hexsos_argmin"][0].shape == (len(H), 3)


def test_demo_default_output_goes_to_the_working_directory(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["demo", "--json", "--no-picture"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert os.path.exists(tmp_path / "hexsos-demo.vtu") and d["invalid_inside_only"] >= 1
    assert d["picture"] is None and not os.path.exists(tmp_path / "hexsos-demo.png")


def test_check_summary_and_exit_code(demo_file, capsys, demo_arrays):
    before = _fingerprint(demo_file)
    assert cli.main(["check", str(demo_file)]) == 1  # invalid hexes: exit 1
    text = capsys.readouterr().out
    ref = hs.check(*demo_arrays[:2])
    assert f"invalid    {ref.counts()['invalid']} " in text
    assert f"of which {ref.counts()['invalid_inside_only']} invalid inside only" in text
    assert "min det J" in text and f"hex {ref.worst}" in text
    assert _fingerprint(demo_file) == before  # the input is never touched


def test_check_all_valid_exits_zero(tmp_path, capsys):
    P, H = structured_grid(3)
    path = tmp_path / "grid.vtk"
    meshio.write(path, meshio.Mesh(P, [("hexahedron", H)]))
    assert cli.main(["check", str(path)]) == 0
    assert "valid      27 (100.00%)" in capsys.readouterr().out


def test_check_json(demo_file, capsys, demo_arrays):
    assert cli.main(["check", str(demo_file), "--json"]) == 1
    d = json.loads(capsys.readouterr().out)
    ref = hs.check(*demo_arrays[:2])
    for key in ("hexes", "valid", "invalid", "undecided", "invalid_inside_only", "min_det", "worst_hex",
                "worst_argmin", "seconds"):
        assert key in d
    assert d["invalid"] == ref.counts()["invalid"] and d["worst_hex"] == ref.worst
    assert d["min_det"] == pytest.approx(float(ref.min_det.min()))


@pytest.mark.parametrize("ext", [".vtu", ".vtk", ".msh"])
def test_check_output_keeps_everything_and_adds_the_arrays(demo_file, tmp_path, ext, demo_arrays):
    out = tmp_path / f"out{ext}"
    assert cli.main(["check", str(demo_file), "-o", str(out), "--method", "auto"]) == 1
    m = read_meshio(out)  # meshio 5.3.5 itself cannot read back multi-block .msh with cell data
    types = [b.type for b in m.cells]
    assert "hexahedron" in types and "quad" in types
    hexblock = types.index("hexahedron")
    ref = hs.check(*demo_arrays[:2])
    assert np.array_equal(m.cell_data["hexsos_status"][hexblock].astype(int), ref.status)
    assert np.allclose(m.cell_data["hexsos_min_det"][hexblock], ref.min_det)
    assert np.allclose(m.point_data["temperature"], np.arange(len(m.points)))
    assert "region" in m.cell_data


def test_check_uses_every_core_by_default_and_one_with_jobs_1(tmp_path, capsys, monkeypatch):
    """The command line runs the kernel on every core this process may use unless told otherwise (the same
    verdicts as one thread); where worker processes or a cluster do the work, each runs one thread."""
    import argparse

    from hexsos_plugins import kernel
    from hexsos_plugins.cli.common import resolve_run_options

    P, H = structured_grid(30)  # 27,000 hexes: several tasks of cells
    path = tmp_path / "grid.vtu"
    meshio.write(path, meshio.Mesh(P, [("hexahedron", H)]))
    seen = []
    run_cells = kernel.run_cells

    def spy(*a, **k):  # the kernel's thread setting at each call
        seen.append(kernel.threads())
        return run_cells(*a, **k)

    monkeypatch.setattr(kernel, "run_cells", spy)
    runs = {}
    for extra in ([], ["--jobs", "1"]):
        seen.clear()
        assert cli.main(["check", str(path), "--json", "--no-progress"] + extra) == 0
        runs[tuple(extra)] = (json.loads(capsys.readouterr().out), set(seen))
    (default, threads), (one, single) = runs[()], runs[("--jobs", "1")]
    assert threads == {kernel.cores()} and single == {1}
    assert default["valid"] == one["valid"] == 27000
    assert kernel.threads() == 1  # restored after the command
    ns = argparse.Namespace
    assert resolve_run_options(ns(jobs=None, processes=1, scheduler=None)).jobs == 0
    assert resolve_run_options(ns(jobs=None, processes=2, scheduler=None)).jobs == 1
    assert resolve_run_options(ns(jobs=None, processes=1, scheduler="tcp://h:8786")).jobs == 1
    assert resolve_run_options(ns(jobs=3, processes=2, scheduler=None)).jobs == 3  # an explicit choice stays
    # the paper's repair counts processes with --jobs: one by default, the optimizer every core
    assert resolve_run_options(ns(jobs=None, processes=1, scheduler=None, method="paper")).jobs == 1
    assert resolve_run_options(ns(jobs=None, processes=1, scheduler=None, method="optimize")).jobs == 0


def test_a_just_in_time_compilation_is_announced_and_nothing_else(tmp_path, monkeypatch, capsys):
    """Where the kernel would compile just in time (no extension for this source, nothing in numba's cache) the
    command says so on stderr before the wait; with the extension, or a warm cache, or for a command that runs
    no kernel, it says nothing. numba's cache is read for real: a fresh cache=True function has none until its
    first call."""
    import argparse
    import importlib
    from types import SimpleNamespace

    from hexsos_plugins.cli.common import announce_compilation
    from hexsos_plugins.kernel import compiled as kcompiled

    (tmp_path / "hexsos_tiny_jit.py").write_text(
        "from numba import njit\n\n\n@njit(cache=True)\ndef f(x):\n    return x + 1\n\n\n"
        "@njit(cache=True)\ndef g(x):\n    return x + 2\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    tiny = importlib.import_module("hexsos_tiny_jit")
    assert kcompiled.jit_cached(tiny.f) is False
    assert tiny.f(1) == 2
    assert kcompiled.jit_cached(tiny.f) is True and kcompiled.jit_cached(tiny.g) is False
    assert kcompiled.jit_cached(object()) is None  # not a cached numba function: unknown, no notice
    runs = argparse.Namespace(jobs=0)
    monkeypatch.setattr(kcompiled, "KIND", "jit")
    monkeypatch.setattr(kcompiled, "impl", SimpleNamespace(run_chunk=tiny.g))
    assert announce_compilation(runs) and "compiling the kernel just in time" in capsys.readouterr().err
    assert not announce_compilation(argparse.Namespace())  # a command without the kernel
    monkeypatch.setattr(kcompiled, "impl", SimpleNamespace(run_chunk=tiny.f))  # cached: no wait, no notice
    assert not announce_compilation(runs)
    monkeypatch.setattr(kcompiled, "KIND", "aot")
    monkeypatch.setattr(kcompiled, "impl", SimpleNamespace(run_chunk=tiny.g))
    assert not announce_compilation(runs) and capsys.readouterr().err == ""


def test_left_handed_file_is_named_and_can_be_fixed(tmp_path, capsys):
    P, H = structured_grid(2)
    mirrored = H[:, [0, 3, 2, 1, 4, 7, 6, 5]]
    path = tmp_path / "left.vtu"
    meshio.write(path, meshio.Mesh(P, [("hexahedron", mirrored)]))
    assert cli.main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "left-handed" in err and "--fix-orientation" in err and len(err.strip().splitlines()) == 1
    assert cli.main(["check", str(path), "--fix-orientation"]) == 0
    assert "valid      8 (100.00%)" in capsys.readouterr().out
    # the repair flips them too, says so and writes the file in the right-handed order
    out = tmp_path / "fixed.vtu"
    assert cli.main(["repair", str(path), "-o", str(out), "--fix-orientation", "--no-fidelity"]) == 0
    assert "orientation: left-handed (hexahedron), flipped (--fix-orientation)" in capsys.readouterr().out
    assert np.array_equal(meshio.read(out).cells_dict["hexahedron"], H)


def test_a_mirrored_block_beside_a_right_handed_one_is_named_and_can_be_fixed(tmp_path, capsys):
    P, H = structured_grid(2)
    half = P[H[:, 0], 0] == P[:, 0].min()
    some = H.copy()
    some[half] = some[half][:, [0, 3, 2, 1, 4, 7, 6, 5]]
    path = tmp_path / "half.vtu"
    meshio.write(path, meshio.Mesh(P, [("hexahedron", some)]))
    assert cli.main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    rows = ", ".join(map(str, np.flatnonzero(half)))
    assert f"partly mirrored: 4 of the 8 hexahedron cells (cells {rows})" in err and "--fix-orientation" in err
    assert cli.main(["check", str(path), "--fix-orientation", "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["valid"] == 8 and d["orientation"] == "mirrored (4 hexahedron cells) (flipped)"
    # the input is never modified
    assert np.array_equal(meshio.read(path).cells_dict["hexahedron"], some)


@pytest.mark.parametrize("content,name,match", [
    (None, "missing.vtu", "no such file"),
    (b"", "empty.vtk", "empty"),
    (b"\x00\xff\x13garbage\x00" * 50, "garbage.vtk", "could not read"),
    (b"hello", "mesh.xyz", "extension"),
])
def test_bad_input_one_line_exit_2(tmp_path, capsys, content, name, match):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    assert cli.main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hexsos: error: ") and match in err and len(err.strip().splitlines()) == 1


def test_no_3d_cells(tmp_path, capsys):
    path = tmp_path / "tris.vtu"
    meshio.write(path, meshio.Mesh(np.eye(4, 3), [("triangle", np.array([[0, 1, 2], [1, 2, 3]]))]))
    assert cli.main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "expected 3-D cells" in err and "found 2 triangle" in err and len(err.splitlines()) == 1


def test_console_script_prints_no_traceback(tmp_path):
    bad = tmp_path / "bad.mesh"
    bad.write_text("MeshVersionFormatted 1\nVertices\nabc\n")
    r = subprocess.run([sys.executable, "-m", "hexsos_plugins", "check", str(bad)], capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr and "bad.mesh" in r.stderr


def test_progress_bar_on_request(tmp_path, capsys):
    path = tmp_path / "one.vtu"
    meshio.write(path, meshio.Mesh(inside_invalid_hex(), [("hexahedron", np.arange(8)[None])]))
    assert cli.main(["check", str(path), "--progress"]) == 1
    assert "100.0%" in capsys.readouterr().err
    assert cli.main(["check", str(path)]) == 1  # not a terminal: no bar
    assert "%" not in capsys.readouterr().err


def test_progress_bar_is_one_line_rewritten_in_place():
    """Calls at the total (the repair's steps after its last bad cell) rewrite the bar's one line with the note
    after it; the line ends once, at ``close``; a shorter line blanks out the longer one before it."""
    import io
    import time

    from hexsos_plugins.cli.common import Progress

    s = io.StringIO()
    bar = Progress("repairing", enabled=True, stream=s)
    bar(0, 5)
    bar(5, 5)
    for note in ("raising the quality, 3 s", "joint steps, 9 s", "x"):
        time.sleep(0.12)
        bar.note(note)
        bar(5, 5)
    bar.close()
    bar.close()
    out = s.getvalue()
    assert out.count("\n") == 1 and out.endswith("\n"), repr(out)
    frames = out[:-1].split("\r")[1:]
    assert [f.rstrip() for f in frames] == [
        "repairing [..............................]   0.0% 0/5",
        "repairing [##############################] 100.0% 5/5",
        "repairing [##############################] 100.0% 5/5  raising the quality, 3 s",
        "repairing [##############################] 100.0% 5/5  joint steps, 9 s",
        "repairing [##############################] 100.0% 5/5  x"], frames
    assert len(frames[-1]) == len(frames[-2].rstrip())  # blanks over the longer line's tail
    quiet = io.StringIO()
    bar = Progress("repairing", enabled=False, stream=quiet)
    bar(5, 5)
    bar.note("joint steps")
    bar.close()
    assert quiet.getvalue() == ""


def test_repair_progress_names_the_stage_on_one_line(tmp_path, capsys):
    """``hexsos repair --progress``: one bar line, at the end the stage under way and its seconds after it (the
    bar counts cells repaired, full long before the quality stages end)."""
    import re

    P, H = structured_grid(3)
    P[(1 * 4 + 1) * 4 + 1, 2] -= 0.5
    src, out = tmp_path / "in.vtu", tmp_path / "out.vtu"
    meshio.write(str(src), meshio.Mesh(P, [("hexahedron", H)]))
    assert cli.main(["repair", str(src), "-o", str(out), "--progress", "--no-fidelity"]) == 0
    err = capsys.readouterr().err
    lines = [ln for ln in err.split("\n") if "repairing [" in ln]
    assert len(lines) == 1, err
    last = lines[0].split("\r")[-1].rstrip()
    words = ("untangling|smoothing|raising the quality|vertex steps|joint steps|standing quads back up|"
             "back into the band")
    assert re.fullmatch(rf"repairing \[#{{30}}\] 100\.0% (\d+)/\1  ({words}), \d+ s", last), last


def test_interrupt_exits_130_without_traceback_or_output(tmp_path):
    """A real SIGINT while the kernel runs (sent from its first progress report, so no timing is involved):
    exit 130, one line, no traceback, no half-written output."""
    path = tmp_path / "mesh.vtu"
    P, H = structured_grid(4)
    meshio.write(path, meshio.Mesh(P, [("hexahedron", H)]))
    out = tmp_path / "out.vtu"
    script = (
        "import os, signal, sys\n"
        "from hexsos_plugins import certify, cli\n"
        "real = certify.check\n"
        "def check(*a, progress=None, **k):\n"
        "    def report(done, total):\n"
        "        os.kill(os.getpid(), signal.SIGINT)\n"
        "    return real(*a, progress=report, **k)\n"
        "certify.check = check\n"
        f"sys.exit(cli.main(['check', {str(path)!r}, '-o', {str(out)!r}]))\n")
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode == 130, r.stderr
    assert r.stderr.strip() == "hexsos: interrupted" and not out.exists()
