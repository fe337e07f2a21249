"""A wheel install works like the editable one: ``pip install .`` (not ``-e``) into a fresh virtual environment,
then ``hexsos demo``, ``hexsos paraview`` (the real ParaView GUI under Xvfb), ``hexsos gmsh --help`` and the plugin
file loaded from site-packages by ``pvpython``, with no HEXSOS_* variable set.

The environment sees this Python's packages (numpy, clarabel, ... are not reinstalled) and gets hexsos itself
from a wheel built from a copy of the working tree, with the kernel extension the checkout runs put where
``pip install .`` builds it (:func:`_add_compiled_kernel`); every test asserts that the files ParaView loaded are the
wheel's, in the environment's site-packages, not the checkout. "This Python" is the one running the tests: when it
is itself a virtual environment (the README's Quickstart in a user's venv), ``--system-site-packages`` alone
would give the nested environment the *base* interpreter's packages, not the venv's, so a ``.pth`` file adds the
venv's site-packages behind the nested environment's own (:func:`_outer_site_packages`).
"""

import importlib.metadata
import importlib.util
import json
import os
import shutil
import subprocess
import sys
import sysconfig
import textwrap

import numpy as np
import pytest

import hexsos_plugins as hs
from hexsos_plugins.cli import doors as cli_doors
from xserver import virtual_display

PVPYTHON = shutil.which("pvpython")
PARAVIEW = shutil.which("paraview")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(hs.__file__)))
PACKAGES = ("hexsos_plugins", "gmsh_plugin", "vtk_filter", "comparison")  # pyproject's packages.find include

pytestmark = pytest.mark.skipif(PVPYTHON is None or PARAVIEW is None,
                                reason="ParaView is not installed (apt-get install paraview python3-paraview)")


class WheelEnv:
    def __init__(self, base):
        self.base = base
        self.venv = base / "venv"
        self.bin = self.venv / "bin"
        self.python = str(self.bin / "python")
        self.hexsos = str(self.bin / "hexsos")
        self.site = str(self.venv / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}" / "site-packages")
        self.plugin = os.path.join(self.site, "vtk_filter", "hexsos_paraview_plugin.py")

    def env(self, config, **extra):
        """A new user's shell in this environment: its bin first on PATH, no HEXSOS_* nor Python/ParaView paths."""
        env = {k: v for k, v in os.environ.items() if not k.startswith("HEXSOS_")
               and k not in ("PYTHONPATH", "PYTHONHOME", "PV_PLUGIN_PATH", "VIRTUAL_ENV", "DISPLAY")}
        env["PATH"] = f"{self.bin}{os.pathsep}{os.environ.get('PATH', '')}"
        env["XDG_CONFIG_HOME"] = str(config)
        env.update(extra)
        return env


def run(args, cwd, env, timeout=600):
    return subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=timeout, check=False)


def _version(dist):
    """The installed version of ``dist`` as (major, minor), without importing it (importing setuptools here,
    after another test imported distutils, trips setuptools' distutils check)."""
    try:
        return tuple(int(x) for x in importlib.metadata.version(dist).split(".")[:2])
    except (importlib.metadata.PackageNotFoundError, ValueError):
        return None


def _can_build_without_isolation():
    if importlib.util.find_spec("wheel") is not None:
        return True
    return (_version("setuptools") or (0, 0)) >= (70, 1)  # setuptools >= 70.1 builds wheels on its own


def _outer_site_packages():
    """The site-packages of the Python running the tests when it is a virtual environment (else [], the base
    interpreter's being what ``--system-site-packages`` adds)."""
    import site

    if sys.prefix == sys.base_prefix:
        return []
    return [d for d in site.getsitepackages() if os.path.isdir(d)]


def _see_outer_packages(w):
    """Let the nested environment import what the running venv holds (after its own packages: the wheel's hexsos
    wins). ``site.addsitedir`` also runs the venv's own ``.pth`` files, as ``--system-site-packages`` does."""
    outer = _outer_site_packages()
    if outer:
        lines = [f"import site; site.addsitedir({d!r})" for d in outer]
        with open(os.path.join(w.site, "_hexsos_test_outer_venv.pth"), "w") as fh:
            fh.write("\n".join(lines) + "\n")
    return outer


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    base = tmp_path_factory.mktemp("wheel")
    src = base / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(os.path.join(ROOT, name), src / name)
    for pkg in PACKAGES:
        shutil.copytree(os.path.join(ROOT, pkg), src / pkg,
                        ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info"))
    w = WheelEnv(base)
    outside = (_version("pip") or (0, 0)) >= (22, 3)  # pip --python: no pip needed inside the environment
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages"] + (["--without-pip"] if outside else [])
                   + [str(w.venv)], check=True, timeout=300)
    _see_outer_packages(w)
    pip_cmd = [sys.executable, "-m", "pip", "--python", w.python] if outside else [w.python, "-m", "pip"]
    install = pip_cmd + ["install", "--no-deps", "--no-input", "-q"]
    if not _can_build_without_isolation():  # setuptools < 70.1 needs the wheel package to build a wheel
        proc = subprocess.run(install + ["wheel"], capture_output=True, text=True, timeout=600, check=False)
        assert proc.returncode == 0, proc.stdout + proc.stderr
    # the build uses this Python's setuptools (and what else the build needs) instead of fetching them
    proc = subprocess.run(install + ["--no-build-isolation", str(src)], capture_output=True, text=True, timeout=900,
                          check=False)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    _add_compiled_kernel(w)
    return w


def _add_compiled_kernel(w):
    """The kernel extension ``pip install .`` builds (setup.py, which the copy leaves out: its build takes minutes),
    taken from the checkout when the checkout runs it (built from this very source). Without it the environment
    compiles the kernel at first use, 90 s of ``hexsos demo``'s first run there (measured; 2.7 s once cached), and
    ParaView's and pvpython's runs compiled it again."""
    from hexsos_plugins.kernel import compiled

    if compiled.implementation() != "aot":
        return
    dest = os.path.join(w.site, "hexsos_plugins", "kernel")
    shutil.copy2(compiled.impl.__file__, dest)
    proc = run([w.python, "-c", "import hexsos_plugins.kernel as k; print(k.implementation(), k.__file__)"], w.base,
               w.env(w.base / "config"))
    assert proc.stdout.split() == ["aot", os.path.join(dest, "__init__.py")], proc.stdout + proc.stderr


def test_the_wheel_holds_every_module_and_the_package_data(wheel, tmp_path):
    for pkg in PACKAGES:  # every module of the working tree, subpackages (hexsos_plugins.io.readers) included
        for folder, dirs, files in os.walk(os.path.join(ROOT, pkg)):
            dirs[:] = [d for d in dirs if d != "__pycache__"]
            for f in files:
                if f.endswith(".py"):
                    rel = os.path.relpath(os.path.join(folder, f), ROOT)
                    assert os.path.isfile(os.path.join(wheel.site, rel)), f"{rel} is not in the wheel"
    assert os.path.isfile(os.path.join(wheel.site, "vtk_filter", "paraview_compat", "usercustomize.py"))
    # the environment imports the wheel's copy, not the checkout
    proc = run([wheel.python, "-c", "import hexsos_plugins, vtk_filter, gmsh_plugin, hexsos_plugins.io.readers as r; "
                "print(hexsos_plugins.__file__, vtk_filter.__file__, gmsh_plugin.__file__, r.__file__)"],
               tmp_path, wheel.env(tmp_path / "config"))
    assert proc.returncode == 0, proc.stderr
    assert all(p.startswith(wheel.site + os.sep) for p in proc.stdout.split()), proc.stdout
    for args, needle in ((["gmsh", "--help"], "usage: hexsos gmsh"), (["paraview", "--help"], "--screenshot"),
                         (["--help"], "paraview")):
        proc = run([wheel.hexsos] + args, tmp_path, wheel.env(tmp_path / "config"))
        assert proc.returncode == 0 and needle in proc.stdout, proc.stderr
    proc = run([wheel.bin / "hexsos-gmsh", "--help"], tmp_path, wheel.env(tmp_path / "config"))
    assert proc.returncode == 0 and "--auto-action" in proc.stdout  # the old name still works


# ------------------------------------------------------------------------------------------------------
# the GUI
# ------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def display():
    """A virtual X server of our own, the size of a desktop screen."""
    with virtual_display("1600x1200x24") as name:
        yield name


def _pixels(png):
    Image = pytest.importorskip("PIL.Image")
    a = np.asarray(Image.open(png).convert("RGB")).astype(int)
    r, g, b = a[..., 0], a[..., 1], a[..., 2]
    invalid = (r > 80) & (r > 1.8 * g) & (r > 1.8 * b)  # the status colour of invalid cells, lit or not
    fold = a.max(axis=2) < 45  # the black fold points
    mesh = np.abs(a - a[0, 0]).max(axis=2) > 12  # anything but the background
    left = slice(0, int(0.75 * a.shape[1]))  # the legend (with its swatches) sits at the right
    return {"invalid": int(invalid[:, left].sum()), "invalid_anywhere": int(invalid.sum()),
            "fold": int(fold[:, left].sum()), "mesh": float(mesh[:, left].mean())}


def _report(proc):
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    assert lines, proc.stdout + proc.stderr
    return json.loads(lines[-1])


def test_hexsos_paraview_gui_shows_the_invalid_cells_in_the_status_colour(wheel, display, tmp_path):
    config = tmp_path / "config"
    env = wheel.env(config, DISPLAY=display)
    proc = run([wheel.hexsos, "demo"], tmp_path, env)
    assert proc.returncode == 0, proc.stderr
    demo = tmp_path / "hexsos-demo.vtu"
    mesh = hs.read(str(demo))
    expected = hs.check(mesh.points, mesh.hexes).counts()
    assert expected["invalid"] >= 3 and expected["invalid_inside_only"] >= 1

    shot = tmp_path / "demo.png"
    proc = run([wheel.hexsos, "paraview", demo.name, "--screenshot", shot, "--exit-after", "--json"], tmp_path, env)
    assert proc.returncode == 1, proc.stdout + proc.stderr  # some cell invalid
    report = _report(proc)
    assert report["plugin"] == wheel.plugin and report["kernel"].startswith(wheel.site + os.sep)
    (m,) = report["meshes"]
    assert (m["valid"], m["invalid"], m["undecided"], m["invalid_inside_only"]) == (
        expected["valid"], expected["invalid"], expected["undecided"], expected["invalid_inside_only"])
    assert m["fold_points"] == expected["invalid"]
    seen = _pixels(shot)
    assert seen["invalid"] > 2000 and seen["fold"] > 10 and seen["mesh"] > 0.05, seen

    # the same ring undamaged, carrying the damaged file's stale hexsos_status (17 cells "invalid"): ParaView
    # must show what the check finds now, none invalid, not what the file says
    import meshio

    from hexsos_plugins.examples import gmsh_mesh

    P0, H0 = gmsh_mesh("ring", 6)
    old = meshio.read(str(demo))
    assert np.array_equal(old.cells[0].data, H0) and 0 in old.cell_data["hexsos_status"][0]
    valid = tmp_path / "valid.vtu"
    meshio.Mesh(P0, [("hexahedron", H0)], cell_data=old.cell_data).write(str(valid))
    shot_valid = tmp_path / "valid.png"
    proc = run([wheel.hexsos, "paraview", valid, "--screenshot", shot_valid, "--exit-after", "--json"], tmp_path, env)
    assert proc.returncode == 0, proc.stdout + proc.stderr  # every cell proven valid
    (m,) = _report(proc)["meshes"]
    assert m["valid"] == m["cells"] == H0.shape[0] and m["fold_points"] == 0
    seen_valid = _pixels(shot_valid)
    assert seen_valid["invalid_anywhere"] == 0 and seen_valid["fold"] == 0, seen_valid
    assert abs(seen_valid["mesh"] - seen["mesh"]) < 0.5 * seen["mesh"]  # the mesh is there, seen the same way


# ------------------------------------------------------------------------------------------------------
# pvpython loads the plugin file from site-packages by hand
# ------------------------------------------------------------------------------------------------------

PVSCRIPT = """
import inspect, json, sys
if not hasattr(inspect, "getargspec"):  # Debian's ParaView 5.11 on Python 3.11
    inspect.getargspec = inspect.getfullargspec
import numpy as np
from paraview import servermanager
from paraview.simple import LoadPlugin, OpenDataFile
from vtkmodules.util.numpy_support import vtk_to_numpy
LoadPlugin(PLUGIN, ns=globals())  # defines HexSOSCheck here
check = HexSOSCheck(Input=OpenDataFile(MESH))
check.UpdatePipeline()
data = servermanager.Fetch(check)
cd = data.GetCellData()
arrays = {cd.GetArrayName(i): vtk_to_numpy(cd.GetArray(i)) for i in range(cd.GetNumberOfArrays())
          if cd.GetArray(i) is not None and cd.GetArrayName(i).startswith("hexsos_")}
np.savez(OUT + ".npz", **arrays)
kernel = sys.modules.get("hexsos_plugins")
json.dump({"kernel": getattr(kernel, "__file__", None), "python": sys.version.split()[0]}, open(OUT, "w"))
"""


def _pvpython(tmp_path, mesh, plugin, env, name):
    out = tmp_path / name
    script = tmp_path / f"{name}.py"
    script.write_text(f"PLUGIN, MESH, OUT = {plugin!r}, {str(mesh)!r}, {str(out)!r}\n" + PVSCRIPT)
    proc = run([PVPYTHON, "--force-offscreen-rendering", script], tmp_path, env)
    assert proc.returncode == 0 and out.exists(), proc.stdout + proc.stderr
    return json.loads(out.read_text()), dict(np.load(f"{out}.npz")), proc


def test_pvpython_loads_the_plugin_from_site_packages_and_reproduces_check(wheel, tmp_path):
    config = tmp_path / "config"
    env = wheel.env(config)
    proc = run([wheel.hexsos, "demo", "--no-picture"], tmp_path, env)  # the first hexsos command records
    assert proc.returncode == 0, proc.stderr
    import meshio

    written = meshio.read(str(tmp_path / "hexsos-demo.vtu"))
    demo = tmp_path / "plain.vtu"  # the demo mesh without the result arrays hexsos demo wrote onto it
    meshio.Mesh(written.points, written.cells).write(str(demo))
    # the reference: check() of the wheel's kernel, in the environment's Python
    ref = tmp_path / "ref.npz"
    proc = run([wheel.python, "-c", textwrap.dedent(f"""
        import numpy as np, hexsos_plugins as hs
        m = hs.read({str(demo)!r})
        np.savez({str(ref)!r}, **hs.check(m.points, m.hexes).cell_data())
    """)], tmp_path, env)
    assert proc.returncode == 0, proc.stderr
    expected = dict(np.load(ref))
    info, got, _ = _pvpython(tmp_path, demo, wheel.plugin, env, "pv")
    assert info["kernel"].startswith(wheel.site + os.sep)
    assert {"hexsos_status", "hexsos_min_det", "hexsos_argmin"} <= set(expected) <= set(got)
    for name, want in expected.items():
        have = got[name]
        assert have.shape == want.shape, name
        if np.issubdtype(want.dtype, np.integer):
            assert np.array_equal(have, want), name
        else:  # ParaView's numpy 1.24 / scipy 1.10 polish the argmin on their own
            atol = 1e-6 if name == "hexsos_argmin" else 1e-9
            assert np.allclose(have, want, rtol=1e-9, atol=atol, equal_nan=True), name
    assert (expected["hexsos_status"] == 0).sum() >= 3

    # a record only for another Python version: the plugin says so, naming both versions
    other = tmp_path / "other-config"
    cli_doors.record_environment(str(other / "hexsos" / "environments.json"), python="3.99.1",
                                 executable=sys.executable, paths=[sysconfig.get_paths()["purelib"]])
    info, got, proc = _pvpython(tmp_path, demo, wheel.plugin, wheel.env(other), "pv-other")
    if "hexsos_status" in got:
        pytest.skip("ParaView's Python finds the kernel's dependencies on its own here")
    assert "cannot import the hexsos kernel" in proc.stderr
    assert "Python 3.99.1" in proc.stderr and f"ParaView runs Python {info['python']}" in proc.stderr


def test_other_formats_are_converted_and_a_mesh_that_cannot_be_checked_is_one_error_line(wheel, display, tmp_path):
    import meshio

    from hexsos_plugins.examples import structured_grid

    P, H = structured_grid(3)
    P[np.flatnonzero(np.all(np.isclose(P, 1 / 3), axis=1))[0], 0] += 0.5  # an interior vertex pushed through
    grid = tmp_path / "grid.vtk"  # not a format ParaView is handed: hexsos reads it and passes a .vtu on
    hs.write(meshio.Mesh(P, [("hexahedron", H)]), str(grid))
    expected = hs.check(P, H).counts()
    tets = tmp_path / "quads.vtu"  # 2-D cells only: nothing to check
    meshio.Mesh(np.eye(4)[:, :3], [("quad", np.array([[0, 1, 2, 3]]))]).write(str(tets))
    fingerprint = {p: p.read_bytes() for p in (grid, tets)}
    proc = run([wheel.hexsos, "paraview", grid, tets, "--exit-after", "--json"], tmp_path,
               wheel.env(tmp_path / "config", DISPLAY=display))
    assert proc.returncode == 2, proc.stdout + proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("hexsos")]
    assert len(errors) == 1 and errors[0].startswith("hexsos: error: quads.vtu: HexSOS Check failed: "), proc.stderr
    assert "no 3-D cells" in errors[0] and "Traceback" not in proc.stderr
    report = _report(proc)
    assert list(report["converted"]) == [str(grid)]
    m, t = report["meshes"]
    assert m["file"] == "grid.vtk" and (m["valid"], m["invalid"], m["undecided"]) == (
        expected["valid"], expected["invalid"], expected["undecided"]) and m["invalid"] > 0
    assert t == {"file": "quads.vtu", "error": errors[0][len("hexsos: error: "):]}
    assert {p: p.read_bytes() for p in (grid, tets)} == fingerprint  # inputs untouched
