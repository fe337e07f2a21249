"""``hexsos paraview`` and ``hexsos gmsh``: the doors, their errors, and the environment record.

Real components throughout: ``pvpython`` (Debian's ParaView 5.11), Gmsh, and for the version mismatch a real
Python of another version standing in for ParaView's (a shell script that answers the probe when there is none).
The GUI and the wheel install are in ``test_doors_wheel.py``.
"""

import glob
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import hexsos_plugins as hs
from hexsos_plugins import cli
from hexsos_plugins.cli import doors as cli_doors
from hexsos_plugins.examples import structured_grid

HEXSOS = [sys.executable, "-m", "hexsos_plugins"]
PVPYTHON = shutil.which("pvpython")
needs_pvpython = pytest.mark.skipif(PVPYTHON is None, reason="pvpython is not installed (apt-get install paraview "
                                    "python3-paraview)")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(hs.__file__)))


def clean_env(tmp_path, **extra):
    """This environment as a new user's: no HEXSOS_* variables, no Python or ParaView paths, a fresh config."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith("HEXSOS_") and k not in ("PYTHONPATH", "PYTHONHOME", "PV_PLUGIN_PATH", "VIRTUAL_ENV")}
    env["XDG_CONFIG_HOME"] = str(tmp_path / "config")
    env.update(extra)
    return env


def run(args, tmp_path, env=None, **kw):
    return subprocess.run(args, cwd=tmp_path, env=env or clean_env(tmp_path), capture_output=True, text=True,
                          timeout=600, check=False, **kw)


def damaged_mesh(path, *, damage=True):
    """A 3x3x3 grid (27 hexes), with one interior vertex pushed through its neighbours if ``damage``."""
    P, H = structured_grid(3)
    if damage:
        P[np.flatnonzero(np.all(np.isclose(P, 1 / 3), axis=1))[0], 0] += 0.5
    import meshio

    hs.write(meshio.Mesh(P, [("hexahedron", H)]), str(path))
    return str(path), hs.check(P, H)


def quiet(proc):
    """Nothing on stderr about an error (other code may warn; the record never speaks)."""
    return not any(w in proc.stderr for w in ("Traceback", "hexsos: error", "environments", "a-file"))


def one_line_error(proc):
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("hexsos: error: "), (
        proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr
    return lines[0]


# ------------------------------------------------------------------------------------------------------
# one command, every door
# ------------------------------------------------------------------------------------------------------


def test_hexsos_help_lists_every_door(tmp_path):
    proc = run(HEXSOS + ["--help"], tmp_path)
    assert proc.returncode == 0
    listed = re.findall(r"^    (\w+)\s", proc.stdout, flags=re.M)
    assert {"check", "repair", "convert", "demo", "paraview", "gmsh"} <= set(listed), proc.stdout
    assert run(HEXSOS + ["nosuchdoor"], tmp_path).returncode == 2


def _gmsh_lines(proc):
    return [line for line in proc.stdout.splitlines() if not line.startswith("time")]  # the run time differs


def test_hexsos_gmsh_is_the_hexsos_gmsh_door(tmp_path):
    pytest.importorskip("gmsh")
    bad, expected = damaged_mesh(tmp_path / "bad.msh")
    good, _ = damaged_mesh(tmp_path / "good.msh", damage=False)
    old = [sys.executable, "-m", "gmsh_plugin"]  # what the hexsos-gmsh console script runs
    for mesh, code in ((bad, 1), (good, 0)):
        new_proc = run(HEXSOS + ["gmsh", mesh, "-nopopup"], tmp_path)
        old_proc = run(old + [mesh, "-nopopup"], tmp_path)
        assert new_proc.returncode == old_proc.returncode == code, (new_proc.stderr, old_proc.stderr)
        assert _gmsh_lines(new_proc) == _gmsh_lines(old_proc)
    text = run(HEXSOS + ["gmsh", bad, "-nopopup"], tmp_path).stdout
    assert re.search(rf"^invalid\s+{expected.counts()['invalid']}\b", text, flags=re.M), text
    helped = run(HEXSOS + ["gmsh", "--help"], tmp_path)
    assert helped.returncode == 0 and helped.stdout.startswith("usage: hexsos gmsh")
    assert "--auto-action" in helped.stdout and "-nopopup" in helped.stdout
    # errors keep the door's one-line form, named after the command that was run
    proc = run(HEXSOS + ["gmsh", str(tmp_path / "missing.msh"), "-nopopup"], tmp_path)
    assert proc.returncode == 2 and proc.stderr.strip().splitlines() == [
        f"hexsos gmsh: error: {tmp_path / 'missing.msh'}: no such file"]


# ------------------------------------------------------------------------------------------------------
# hexsos paraview: errors before ParaView starts
# ------------------------------------------------------------------------------------------------------


def test_no_paraview_on_path_is_one_line_and_exit_2(tmp_path):
    mesh, _ = damaged_mesh(tmp_path / "m.vtu")
    empty = tmp_path / "bin"
    empty.mkdir()
    env = clean_env(tmp_path, PATH=str(empty))
    line = one_line_error(run(HEXSOS + ["paraview", mesh], tmp_path, env))
    assert "ParaView not found: no 'paraview' on PATH" in line and "apt-get install paraview" in line
    line = one_line_error(run(HEXSOS + ["paraview", "--script", mesh], tmp_path, env))
    assert "pvpython (ParaView's Python) not found" in line
    line = one_line_error(run(HEXSOS + ["paraview", mesh, "--paraview", str(empty / "paraview")], tmp_path, env))
    assert "--paraview" in line and "no such file" in line
    # found, but nothing to show it on (ParaView's Qt would abort): said before it starts
    fake = _script(empty / "paraview", f'#!/bin/sh\ntouch "{tmp_path / "started"}"\n')
    no_x = {k: v for k, v in env.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM")}
    line = one_line_error(run(HEXSOS + ["paraview", mesh, "--paraview", fake], tmp_path, no_x))
    assert "no display for ParaView's GUI" in line and "xvfb-run" in line and not (tmp_path / "started").exists()
    # a missing MESH is refused before ParaView starts
    line = one_line_error(run(HEXSOS + ["paraview", str(tmp_path / "nothere.vtu"), "--paraview", fake], tmp_path,
                              dict(env, DISPLAY=":0")))
    assert line.endswith("nothere.vtu: no such file") and not (tmp_path / "started").exists()


def _other_python():
    """A real Python whose major.minor differs from this one's, or None."""
    mine = f"{sys.version_info[0]}.{sys.version_info[1]}"
    candidates = [shutil.which(f"python3.{m}") for m in range(6, 20)]
    candidates += sorted(glob.glob(os.path.expanduser("~/.pyenv/versions/3.*/bin/python3.*")))
    for exe in candidates:
        if not exe or not os.access(exe, os.X_OK) or exe.endswith("-config"):
            continue
        proc = subprocess.run([exe, "-c", "import sys, platform; print(platform.python_version())"],
                              capture_output=True, text=True, timeout=60, check=False)
        version = proc.stdout.strip()
        if proc.returncode == 0 and version and ".".join(version.split(".")[:2]) != mine:
            return exe, version
    return None


def _script(path, text):
    path.write_text(text)
    path.chmod(0o755)
    return str(path)


def test_paraview_whose_python_differs_is_refused_naming_both_versions(tmp_path):
    mesh, _ = damaged_mesh(tmp_path / "m.vtu")
    fake = tmp_path / "fakebin"
    fake.mkdir()
    marker = tmp_path / "paraview-started"
    other = _other_python()
    if other is not None:  # ParaView's "pvpython" is a real interpreter of another version
        exe, version = other
        _script(fake / "pvpython", f'#!/bin/sh\nexec "{exe}" "$@"\n')
    else:  # answers the launcher's probe as a Python 3.99 would
        version = "3.99.0"
        _script(fake / "pvpython", "#!/bin/sh\necho 'HEXSOS-PROBE "
                '{"python": "3.99.0", "executable": "/opt/fake/pvpython", "paraview": "/opt/fake/paraview"}\'\n')
    _script(fake / "paraview", f'#!/bin/sh\ntouch "{marker}"\n')
    env = clean_env(tmp_path, PATH=f"{fake}{os.pathsep}{os.environ['PATH']}", DISPLAY=":0")  # never opened
    line = one_line_error(run(HEXSOS + ["paraview", mesh], tmp_path, env))
    assert f"ParaView's Python is {version}" in line and f"hexsos runs on Python {platform.python_version()}" in line
    assert "clarabel" in line
    assert not marker.exists()  # refused before the GUI starts
    # with the probe passing (the real pvpython, of this version), the start-up script checks ParaView's own Python
    if other is not None and PVPYTHON is not None:
        exe, version = other
        _script(fake / "pvpython", f'#!/bin/sh\nexec "{PVPYTHON}" "$@"\n')
        _script(fake / "paraview", f'#!/bin/sh\ntouch "{marker}"\nexec "{exe}" "${{1#--script=}}"\n')
        line = one_line_error(run(HEXSOS + ["paraview", mesh, "--exit-after"], tmp_path, env))
        assert marker.exists()
        assert f"ParaView's Python is {version}" in line and f"Python {platform.python_version()}" in line


# ------------------------------------------------------------------------------------------------------
# hexsos paraview --script: pvpython with the plugin loaded and this environment's packages
# ------------------------------------------------------------------------------------------------------


@needs_pvpython
def test_script_runs_in_pvpython_with_the_plugin_and_this_environment(tmp_path):
    mesh, expected = damaged_mesh(tmp_path / "m.vtu")
    out = tmp_path / "out.json"
    script = tmp_path / "batch.py"
    script.write_text(textwrap.dedent(f"""
        import json, sys
        from paraview.simple import HexSOSCheck, OpenDataFile
        check = HexSOSCheck(Input=OpenDataFile(sys.argv[1]))
        check.UpdatePipeline()
        result = check.GetClientSideObject().GetResult()
        import hexsos_plugins, vtkmodules
        json.dump({{"argv": sys.argv[1:], "status": result.status.tolist(), "kernel": hexsos_plugins.__file__,
                   "vtk": vtkmodules.__file__, "path": sys.path}}, open({str(out)!r}, "w"))
        sys.exit(3)
    """))
    # a new user's environment: nothing set, nothing recorded (auto-recording off): the launcher hands it over
    env = clean_env(tmp_path, HEXSOS_NO_RECORD="1")
    proc = run(HEXSOS + ["paraview", "--script", str(script), mesh, "extra-arg"], tmp_path, env)
    assert proc.returncode == 3, proc.stderr  # the script's exit code
    res = json.loads(out.read_text())
    assert res["argv"] == [mesh, "extra-arg"]
    assert res["status"] == expected.status.tolist() and 0 in res["status"]
    assert res["kernel"] == hs.__file__
    # this environment's entries come after ParaView's own (PyPI's VTK ahead of ParaView's would crash it)
    assert not any(res["vtk"].startswith(p) for p in cli_doors.environment_paths())
    ours = [i for i, p in enumerate(res["path"]) if p in cli_doors.environment_paths()]
    assert ours and res["path"].index(os.path.dirname(os.path.dirname(res["vtk"]))) < min(ours)
    assert not (tmp_path / "config" / "hexsos").exists()  # HEXSOS_NO_RECORD: nothing recorded
    # a pvpython that dies before the start-up script runs: one line, exit 2
    dead = _script(tmp_path / "dead-pvpython", "#!/bin/sh\nexit 7\n")
    line = one_line_error(run(HEXSOS + ["paraview", "--script", str(script), "--pvpython", dead], tmp_path, env))
    assert "exited with code 7 before the hexsos start-up script ran" in line


# ------------------------------------------------------------------------------------------------------
# the environment record (written by every hexsos command, read by the plugin)
# ------------------------------------------------------------------------------------------------------


def test_environment_paths_hold_the_kernel_and_its_dependencies():
    import importlib.util

    paths = cli_doors.environment_paths()
    assert paths[0] == ROOT  # where hexsos_plugins is, even for an editable install (a finder, not sys.path)
    for dep in ("clarabel", "meshio", "scipy"):
        origin = importlib.util.find_spec(dep).origin
        assert any(origin.startswith(p + os.sep) for p in paths), (dep, origin)
    stdlib = os.path.dirname(os.__file__)
    assert stdlib not in paths and all(os.path.isdir(p) for p in paths) and len(set(paths)) == len(paths)


def test_every_hexsos_command_records_its_environment(tmp_path):
    mesh, _ = damaged_mesh(tmp_path / "m.vtu")
    config = tmp_path / "config" / "hexsos" / "environments.json"
    config.parent.mkdir(parents=True)
    other = {"python": "3.99.1", "executable": shutil.which("sh"), "hexsos": "0.0", "paths": ["/opt/x"]}
    gone = {"python": "3.11.0", "executable": str(tmp_path / "deleted" / "python"), "paths": []}
    config.write_text(json.dumps({"environments": [other, gone]}))
    proc = run(HEXSOS + ["check", mesh], tmp_path)
    assert proc.returncode == 1 and quiet(proc), proc.stderr
    entries = json.loads(config.read_text())["environments"]
    assert [e["executable"] for e in entries] == [sys.executable, other["executable"]]  # newest first, gone dropped
    mine = entries[0]
    assert mine["python"] == platform.python_version() and mine["hexsos"] == hs.__version__
    fresh = run([sys.executable, "-c", "import json; from hexsos_plugins.cli import doors as cli_doors; "
                                       "print(json.dumps(cli_doors.environment_paths()))"], tmp_path)
    assert mine["paths"] == json.loads(fresh.stdout) and mine["paths"][0] == ROOT
    # already first: not rewritten; another Python's run puts its own first
    assert cli_doors.record_environment(str(config), paths=mine["paths"]) is False
    assert cli_doors.record_environment(str(config), python="3.99.1", executable=other["executable"],
                                        paths=["/opt/x"]) is True
    assert [e["executable"] for e in json.loads(config.read_text())["environments"]] == [
        other["executable"], sys.executable]
    # switched off, or a config directory that cannot be written: the command runs as ever, records nothing
    off = run(HEXSOS + ["check", mesh], tmp_path, clean_env(tmp_path / "x", HEXSOS_NO_RECORD="1"))
    assert off.returncode == 1 and not (tmp_path / "x").exists()
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    blocked = run(HEXSOS + ["check", mesh], tmp_path, clean_env(tmp_path, XDG_CONFIG_HOME=str(blocker)))
    assert blocked.returncode == 1 and quiet(blocked) and "invalid" in blocked.stdout, blocked.stderr


def test_the_plugin_reads_the_record_and_names_both_versions(tmp_path, monkeypatch):
    pytest.importorskip("vtkmodules")
    from vtk_filter import hexsos_paraview_plugin as plugin

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))
    monkeypatch.delenv("HEXSOS_PYTHONPATH", raising=False)
    monkeypatch.delenv("VIRTUAL_ENV", raising=False)
    record = tmp_path / "hexsos" / "environments.json"
    here, there = tmp_path / "here", tmp_path / "there"
    here.mkdir()
    there.mkdir()
    assert "no hexsos command has recorded" in plugin.version_note()
    # only another Python version recorded: its paths are not used, and the note names both versions
    cli_doors.record_environment(str(record), python="3.99.1", executable=shutil.which("sh"),
                                 paths=[str(there)])
    assert str(there) not in plugin.dependency_paths()
    note = plugin.version_note()
    assert f"Python 3.99.1 ({shutil.which('sh')})" in note and f"Python {sys.version.split()[0]}" in note
    # this version recorded (more recently): its paths are appended after the plugin's own
    cli_doors.record_environment(str(record), paths=[str(here)])
    assert [e["python"] for e in plugin.recorded_environments()] == [platform.python_version(), "3.99.1"]
    paths = plugin.dependency_paths()
    assert str(here) in paths and str(there) not in paths and plugin.version_note() == ""
    # a damaged record counts as nothing recorded
    record.write_text("{not json")
    assert plugin.recorded_environments() == [] and str(here) not in plugin.dependency_paths()


def test_print_env_names_the_manual_fallback(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))
    assert cli.main(["paraview", "--print-env"]) == 0
    out = capsys.readouterr().out
    folder = os.path.join(ROOT, "vtk_filter")
    assert f"export PV_PLUGIN_PATH={folder}" in out
    assert "export HEXSOS_PYTHONPATH=" + os.pathsep.join(cli_doors.environment_paths()) in out
    assert os.path.join(folder, "paraview_compat") in out


def _children(pid):
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as fh:
            return [int(c) for c in fh.read().split()]
    except OSError:
        return []


def _exe(pid):
    """The executable's name of a process, or None once it has ended."""
    try:
        return os.path.basename(os.readlink(f"/proc/{pid}/exe"))
    except OSError:
        return None


def _alive(pid):
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(shutil.which("paraview") is None or shutil.which("Xvfb") is None or not sys.platform.startswith(
    "linux"), reason="needs ParaView, Xvfb and /proc")
def test_stopping_hexsos_paraview_stops_its_paraview(tmp_path):
    """SIGTERM to ``hexsos paraview`` (a session closed, a job cancelled) closes the ParaView it started."""
    import signal
    import time

    mesh, _ = damaged_mesh(tmp_path / "m.vtu")
    read_end, write_end = os.pipe()
    xvfb = subprocess.Popen(["Xvfb", "-displayfd", str(write_end), "-screen", "0", "1280x1024x24", "-nolisten", "tcp"],
                            pass_fds=(write_end,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write_end)
    display = b""
    while not display.endswith(b"\n"):
        chunk = os.read(read_end, 16)
        if not chunk:
            break
        display += chunk
    os.close(read_end)
    env = clean_env(tmp_path, DISPLAY=":" + display.decode().strip(), PYTHONPATH=ROOT)
    log = open(tmp_path / "door.log", "w+")  # a file, not a pipe: ParaView inherits it and may outlive us
    door = subprocess.Popen(HEXSOS + ["paraview", mesh], cwd=tmp_path, env=env, stdout=log, stderr=log)
    paraview = None
    try:
        deadline = time.monotonic() + 120
        while paraview is None and time.monotonic() < deadline and door.poll() is None:
            found = [c for c in _children(door.pid) if _exe(c) == "paraview"]  # (pvpython is asked first)
            paraview = found[0] if found else None
            time.sleep(0.2)
        assert paraview is not None, "hexsos paraview did not start ParaView"
        time.sleep(3)  # ParaView up (its window, the start-up script)
        door.send_signal(signal.SIGTERM)
        door.wait(timeout=60)
        err = (tmp_path / "door.log").read_text()
        deadline = time.monotonic() + 30
        while _alive(paraview) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not _alive(paraview), "ParaView is still running after hexsos paraview was stopped"
        assert door.returncode == 128 + signal.SIGTERM and "stopped by SIGTERM" in err, err
    finally:
        if door.poll() is None:
            door.kill()
            door.wait()
        if paraview is not None and _alive(paraview):
            os.kill(paraview, signal.SIGKILL)
        xvfb.terminate()
        xvfb.wait(timeout=30)
        log.close()
