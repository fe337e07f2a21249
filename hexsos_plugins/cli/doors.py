"""``hexsos paraview | gmsh``: the doors into ParaView and Gmsh, with nothing to configure.

``hexsos paraview [MESH ...]`` starts the ParaView found on ``PATH`` (or ``--paraview EXE``) with a start-up
script that

1. checks that ParaView's Python has the version of the Python ``hexsos`` runs in (the kernel's compiled
   dependencies, clarabel, load only there); ``pvpython`` beside ``paraview`` is asked first, so a mismatch is
   reported before any window opens;
2. appends this Python's ``sys.path`` (the directories holding ``hexsos_plugins`` and its dependencies,
   without the standard library) to ParaView's: *appended*, never prepended, since PyPI's VTK ahead of
   ParaView's own makes ParaView crash;
3. adds ``inspect.getargspec``, without which Debian's ParaView 5.11 on Python 3.11 loads no Python plugin;
4. loads ``vtk_filter/hexsos_paraview_plugin.py`` of this installation, opens each MESH, applies
   "HexSOS Check" and shows it coloured by ``hexsos_status`` with the fold points
   (``hexsos_paraview_plugin.open_checked``).

``.vtu``/``.pvtu`` files are opened by ParaView itself; every other format is read by hexsos (the tolerant
readers of ``hexsos check``) and handed to ParaView as a temporary ``.vtu``. ``--screenshot PNG`` saves the
view, ``--exit-after`` closes ParaView once the meshes are checked (exit 0 if every checked cell is proven
valid, else 1), ``--script PY`` runs PY in ``pvpython`` (off-screen, the plugin loaded, MESH... as its
arguments) instead of the GUI.

Every ``hexsos`` command also records the environment it runs in (:func:`record_environment`, read by the
plugin's ``recorded_environments``), so the plugin loaded by hand in a ParaView started any other way finds
the kernel too. ``HEXSOS_NO_RECORD=1`` turns that off.

``hexsos gmsh`` is ``hexsos-gmsh`` (:mod:`gmsh_plugin.__main__`) under the one ``hexsos`` command.
"""

from __future__ import annotations

import importlib.util
import json
import os
import platform
import shutil
import subprocess
import sys
import sysconfig
import tempfile

from .._version import __version__
from .common import fail
from ..errors import DependencyError, MeshReadError, MeshWriteError

__all__ = [
    "add_parsers",
    "environment_paths",
    "environments_file",
    "record_environment",
    "auto_record",
    "find_paraview",
    "find_pvpython",
    "paraview_python",
]

#: Files ParaView opens itself; anything else is read by hexsos and handed over as a .vtu.
PARAVIEW_FORMATS = (".vtu", ".pvtu")
#: The size of ``--screenshot`` pictures, in pixels.
SCREENSHOT_SIZE = (1280, 800)
#: How many environments :func:`record_environment` keeps (most recent first).
KEEP_ENVIRONMENTS = 8

_INSTALL_HINT = ("install ParaView >= 5.10 with its Python (Debian/Ubuntu: apt-get install paraview python3-paraview; "
                 "or a binary from https://www.paraview.org/download) or pass --paraview EXE")


# ----------------------------------------------------------------------------------------------------
# This environment, and the record of it the ParaView plugin reads
# ----------------------------------------------------------------------------------------------------


def _python_version() -> str:
    return platform.python_version()


def _minor(version: str) -> str:
    return ".".join(str(version).split(".")[:2])


def environment_paths() -> list:
    """The directories ParaView's Python needs to import hexsos and its dependencies the way this Python does.

    The directory holding ``hexsos_plugins`` and the one holding ``vtk_filter`` (for an editable install they
    are the checkout, which a setuptools finder maps without a ``sys.path`` entry), then this Python's
    ``sys.path`` in order, without its standard library, the script's own directory and entries that are not
    directories. Absolute paths, no duplicates.
    """
    config = sysconfig.get_paths()
    skip = set()
    for key in ("stdlib", "platstdlib"):
        if config.get(key):
            skip.add(os.path.realpath(config[key]))
            skip.add(os.path.realpath(os.path.join(config[key], "lib-dynload")))
    roots = []
    for name in ("hexsos_plugins", "vtk_filter"):
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.origin:
            roots.append(os.path.dirname(os.path.dirname(os.path.abspath(spec.origin))))
    # sys.path[0] is the directory of the script (or the working directory) unless -P / PYTHONSAFEPATH
    entries = sys.path if getattr(sys.flags, "safe_path", False) else sys.path[1:]
    out, seen = [], set()
    for p in roots + list(entries):
        if not p:
            continue
        p = os.path.abspath(p)
        real = os.path.realpath(p)
        if real in skip or real in seen or not os.path.isdir(p):
            continue
        seen.add(real)
        out.append(p)
    return out


def environments_file() -> str:
    """``$XDG_CONFIG_HOME/hexsos/environments.json`` (default ``~/.config``): where environments are recorded."""
    base = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    return os.path.join(base, "hexsos", "environments.json")


def _read_environments(path) -> list:
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, ValueError):
        return []
    entries = data.get("environments") if isinstance(data, dict) else None
    return [e for e in entries if isinstance(e, dict)] if isinstance(entries, list) else []


def record_environment(path=None, *, python=None, executable=None, paths=None,
                       keep: int = KEEP_ENVIRONMENTS) -> bool:
    """Record this environment first in ``path`` (default :func:`environments_file`) for the ParaView plugin.

    The file holds ``{"environments": [...]}``, most recent first, one entry per Python executable: ``python``
    (version, default this Python's), ``executable`` (default ``sys.executable``), ``hexsos`` (version) and
    ``paths`` (default :func:`environment_paths`). Entries of executables that no longer exist are dropped, at
    most ``keep`` are kept. The file is rewritten (atomically) only when this environment is not already first.

    Returns True when the file was written. Raises OSError when it cannot be.
    """
    path = path or environments_file()
    entry = {
        "python": python or _python_version(),
        "executable": executable or sys.executable,
        "hexsos": __version__,
        "paths": list(paths) if paths is not None else environment_paths(),
    }
    entries = _read_environments(path)
    if entries and entries[0] == entry:
        return False
    others = [e for e in entries if e.get("executable") != entry["executable"]
              and isinstance(e.get("executable"), str) and os.path.exists(e["executable"])]
    entries = [entry] + others[:max(keep - 1, 0)]
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = f"{path}.{os.getpid()}.tmp"
    try:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump({"environments": entries}, fh, indent=1)
            fh.write("\n")
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return True


def auto_record() -> None:
    """What every ``hexsos`` command does first: :func:`record_environment`, silently, never failing the
    command (a read-only home just records nothing). ``HEXSOS_NO_RECORD`` set to anything but ``0`` skips it."""
    if os.environ.get("HEXSOS_NO_RECORD", "0") not in ("", "0"):
        return
    try:
        record_environment()
    except (OSError, ValueError, TypeError):
        pass


# ----------------------------------------------------------------------------------------------------
# Finding ParaView and its Python
# ----------------------------------------------------------------------------------------------------


def _executable(exe, what):
    """``exe`` as a path: a name is looked up on PATH. Raises DependencyError if it is not an executable file."""
    found = exe if os.sep in exe or (os.altsep and os.altsep in exe) else shutil.which(exe)
    if not found or not os.path.isfile(found) or not os.access(found, os.X_OK):
        raise DependencyError(f"{what} {exe}: expected an executable file, found "
                              f"{'no such file' if not found or not os.path.exists(found) else 'a file that is not executable'}")
    return os.path.abspath(found)


def find_paraview(exe=None) -> str:
    """The ParaView GUI executable: ``exe`` (a path or a name on PATH), else ``paraview`` on PATH."""
    if exe:
        return _executable(exe, "--paraview")
    found = shutil.which("paraview")
    if not found:
        raise DependencyError(f"ParaView not found: no 'paraview' on PATH; {_INSTALL_HINT}")
    return os.path.abspath(found)


def find_pvpython(exe=None, paraview=None, *, required=True):
    """ParaView's Python interpreter: ``exe``, else ``pvpython`` beside the ``paraview`` executable (also beside
    the file a symlink points to), else ``pvpython`` on PATH. None (or DependencyError if ``required``)."""
    if exe:
        return _executable(exe, "--pvpython")
    if paraview:
        names = ("pvpython.exe", "pvpython") if sys.platform == "win32" else ("pvpython",)
        for folder in dict.fromkeys([os.path.dirname(paraview), os.path.dirname(os.path.realpath(paraview))]):
            for name in names:
                candidate = os.path.join(folder, name)
                if os.path.isfile(candidate) and os.access(candidate, os.X_OK):
                    return candidate
    found = shutil.which("pvpython")
    if found:
        return os.path.abspath(found)
    if required:
        raise DependencyError(f"pvpython (ParaView's Python) not found beside {paraview or 'paraview'} nor on PATH; "
                              f"{_INSTALL_HINT} (or --pvpython EXE)")
    return None


_PROBE = ("import json, sys\n"
          "try:\n"
          "    import paraview\n"
          "    pv = getattr(paraview, '__file__', None) or '?'\n"
          "except ImportError as exc:\n"
          "    pv = None\n"
          "print('HEXSOS-PROBE ' + json.dumps({'python': sys.version.split()[0], 'executable': sys.executable,"
          " 'paraview': pv}))\n")


def paraview_python(pvpython, env=None):
    """What ``pvpython`` says of its Python: ``{"python": "3.11.2", "executable": ..., "paraview": path of its
    ``paraview`` package or None}``, or None when it does not answer (the start-up script checks again)."""
    try:
        proc = subprocess.run([pvpython, "-c", _PROBE], capture_output=True, text=True, timeout=120, env=env,
                              check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    for line in proc.stdout.splitlines():
        if line.startswith("HEXSOS-PROBE "):
            try:
                info = json.loads(line[len("HEXSOS-PROBE "):])
            except ValueError:
                return None
            return info if isinstance(info, dict) and isinstance(info.get("python"), str) else None
    return None


def _mismatch_message(found, executable, minor=None) -> str:
    """The error when ParaView's Python (version ``found``, ``executable``) is not this one's version. Called
    with the placeholders ``{found}``, ``{executable}``, ``{minor}`` for the start-up script, which fills them in."""
    mine = _python_version()
    minor = minor or _minor(found)
    here = sys.executable.replace("{", "{{").replace("}", "}}") if found == "{found}" else sys.executable
    return (f"ParaView's Python is {found} ({executable}), but hexsos runs on Python {mine} ({here}): the "
            f"kernel's compiled dependencies (clarabel) load only in the Python version they were installed for. "
            f"Install hexsos into a Python {minor} environment (e.g. python{minor} -m venv ENV && ENV/bin/pip "
            f"install hexsos) and run its 'hexsos paraview', or use a ParaView built with Python {_minor(mine)}")


def _no_display() -> bool:
    """True on X11/Wayland systems with neither display set (and no Qt platform chosen by hand)."""
    if sys.platform.startswith(("win", "darwin")):
        return False
    return not any(os.environ.get(k) for k in ("DISPLAY", "WAYLAND_DISPLAY", "QT_QPA_PLATFORM"))


def _child_env() -> dict:
    """The environment ParaView starts in: this one without PYTHONHOME/PYTHONPATH (whose entries are handed
    over by appending instead: prepended, a virtual environment's VTK crashes ParaView), and without this
    installation's vtk_filter on PV_PLUGIN_PATH (the start-up script loads the plugin itself)."""
    env = dict(os.environ)
    env.pop("PYTHONHOME", None)
    env.pop("PYTHONPATH", None)
    ours = os.path.realpath(_vtk_filter_dir())
    if env.get("PV_PLUGIN_PATH"):
        kept = [p for p in env["PV_PLUGIN_PATH"].split(os.pathsep) if p and os.path.realpath(p) != ours]
        if kept:
            env["PV_PLUGIN_PATH"] = os.pathsep.join(kept)
        else:
            env.pop("PV_PLUGIN_PATH")
    return env


def _vtk_filter_dir() -> str:
    spec = importlib.util.find_spec("vtk_filter")
    if spec is None or not spec.origin:
        raise DependencyError("the vtk_filter package of hexsos is not installed beside hexsos_plugins: "
                              "reinstall hexsos (pip install hexsos)")
    return os.path.dirname(os.path.abspath(spec.origin))


def _plugin_file() -> str:
    plugin = os.path.join(_vtk_filter_dir(), "hexsos_paraview_plugin.py")
    if not os.path.isfile(plugin):
        raise DependencyError(f"the ParaView plugin file is missing: expected {plugin}; reinstall hexsos")
    return plugin


# ----------------------------------------------------------------------------------------------------
# The start-up script ParaView runs
# ----------------------------------------------------------------------------------------------------

_STARTUP = r'''# The start-up script of `hexsos paraview` (generated; deleted when ParaView exits).
import json

CONFIG = json.loads(%(config)r)


def _hexsos_start(config):
    import inspect
    import os
    import sys

    report = {"error": None, "python": sys.version.split()[0], "executable": sys.executable}

    def finish():
        tmp = config["status"] + ".part"
        with open(tmp, "w") as fh:
            json.dump(report, fh)
        os.replace(tmp, config["status"])
        if config["exit_after"] or (report["error"] and config["script"]):
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(2 if report["error"] else 0)
        if report["error"]:
            raise RuntimeError("hexsos paraview: " + report["error"])

    if "%%d.%%d" %% tuple(sys.version_info[:2]) != config["python"]:
        report["error"] = config["mismatch"].format(found=sys.version.split()[0], executable=sys.executable,
                                                    minor="%%d.%%d" %% tuple(sys.version_info[:2]))
        return finish()
    if not hasattr(inspect, "getargspec"):  # ParaView 5.11's plugin loader on Python >= 3.11
        inspect.getargspec = inspect.getfullargspec
    for path in config["paths"]:
        if path not in sys.path:
            sys.path.append(path)  # appended: ParaView's own vtkmodules, numpy and scipy stay first
    try:
        from paraview import simple

        simple.LoadPlugin(config["plugin"])
        plugin = sys.modules.get("hexsos_paraview_plugin")
        if plugin is None or not hasattr(plugin, "open_checked"):
            raise RuntimeError("ParaView did not load the hexsos plugin " + config["plugin"])
        report["plugin"] = os.path.abspath(plugin.__file__)
        if not config["script"]:
            report.update(plugin.open_checked(config["meshes"], names=config["names"],
                                              screenshot=config["screenshot"], size=config["size"]))
    except Exception as exc:
        report["error"] = " ".join(str(exc).split()) or type(exc).__name__
    finish()
    if config["script"]:  # the set-up worked: from here on the script's errors are the script's own
        import runpy

        sys.argv = [config["script"]] + config["meshes"]
        runpy.run_path(config["script"], run_name="__main__")


_hexsos_start(CONFIG)
'''


def _exist(meshes):
    for mesh in meshes:
        if not os.path.exists(mesh):
            raise MeshReadError(f"{mesh}: no such file")
        if os.path.isdir(mesh):
            raise MeshReadError(f"{mesh}: is a directory, expected a mesh file")


def _prepare_meshes(meshes, workdir):
    """(paths ParaView opens, names shown, conversions): .vtu/.pvtu as they are, others read by hexsos and
    written to ``workdir`` as .vtu. Raises MeshReadError for a missing file or one hexsos cannot read."""
    _exist(meshes)
    paths, names, converted = [], [], {}
    for i, mesh in enumerate(meshes):
        name = os.path.basename(mesh)
        if os.path.splitext(mesh)[1].lower() in PARAVIEW_FORMATS:
            paths.append(os.path.abspath(mesh))
        else:
            from ..io import read, write

            target = os.path.join(workdir, f"{i}-{os.path.splitext(name)[0]}.vtu")
            write(read(mesh).to_meshio(), target)
            paths.append(target)
            converted[mesh] = target
        names.append(name)
    return paths, names, converted


def _writable(path, what):
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
        raise MeshWriteError(f"{what} {path}: expected a writable directory, found "
                            f"{'no directory ' + folder if not os.path.isdir(folder) else folder + ' not writable'}")
    return os.path.abspath(path)


def _cmd_paraview(args) -> int:
    if args.print_env:
        return _print_env()
    if args.script and (args.screenshot or args.exit_after):
        return fail("--screenshot and --exit-after are for the GUI; a --script runs to its end (call "
                    "SaveScreenshot in it)")
    script = None
    if args.script:
        if not os.path.isfile(args.script):
            raise MeshReadError(f"--script {args.script}: no such file")
        script = os.path.abspath(args.script)
        paraview = None
        if not args.pvpython:
            try:
                paraview = find_paraview(args.paraview)
            except DependencyError:
                if args.paraview:
                    raise
        pvpython = find_pvpython(args.pvpython, paraview)
    else:
        paraview = find_paraview(args.paraview)
        pvpython = find_pvpython(args.pvpython, paraview, required=False)
        if _no_display():
            raise DependencyError(
                "no display for ParaView's GUI (DISPLAY is not set): run it in a desktop session or under a virtual "
                "X server (xvfb-run -a hexsos paraview ...), or use --script PY for a batch run in pvpython")
    if not script:
        _exist(args.meshes)
    screenshot = _writable(args.screenshot, "--screenshot") if args.screenshot else None
    plugin = _plugin_file()
    env = _child_env()
    if pvpython:  # ask ParaView's Python before any window opens
        info = paraview_python(pvpython, env)
        if info is not None:
            if _minor(info["python"]) != _minor(_python_version()):
                raise DependencyError(_mismatch_message(info["python"], info.get("executable") or pvpython))
            if info.get("paraview") is None:
                raise DependencyError(f"ParaView's Python ({pvpython}, Python {info['python']}) has no 'paraview' "
                                      "module: install ParaView's Python support (Debian/Ubuntu: apt-get install "
                                      "python3-paraview)")
    workdir = tempfile.mkdtemp(prefix="hexsos-paraview-")
    try:
        if script:
            paths, names, converted = [os.path.abspath(m) if os.path.exists(m) else m for m in args.meshes], [], {}
        else:
            paths, names, converted = _prepare_meshes(args.meshes, workdir)
        status = os.path.join(workdir, "status.json")
        config = {
            "python": _minor(_python_version()),
            "mismatch": _mismatch_message("{found}", "{executable}", "{minor}"),
            "paths": environment_paths(),
            "plugin": plugin,
            "meshes": paths,
            "names": names,
            "screenshot": screenshot,
            "size": list(SCREENSHOT_SIZE),
            "exit_after": bool(args.exit_after),
            "script": script,
            "status": status,
        }
        startup = os.path.join(workdir, "hexsos_startup.py")
        with open(startup, "w", encoding="utf-8") as fh:
            fh.write(_STARTUP % {"config": json.dumps(config)})
        if script:
            command = [pvpython, "--force-offscreen-rendering", startup]
        else:
            command = [paraview, f"--script={startup}"]
        try:
            rc = _run_child(command, env)
        except OSError as exc:
            raise DependencyError(f"could not start {command[0]}: {exc.strerror or exc}") from None
        except _Stopped as stop:  # SIGTERM / SIGHUP: ParaView was closed with us
            sys.stderr.write(f"hexsos: stopped by {stop.name}; {os.path.basename(command[0])} closed\n")
            return 128 + stop.signum
        report = None
        try:
            with open(status, encoding="utf-8") as fh:
                report = json.load(fh)
        except (OSError, ValueError):
            pass
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return _finish(args, report, rc, command[0], converted)


class _Stopped(Exception):
    """This process was asked to stop (SIGTERM, SIGHUP) while ParaView ran."""

    def __init__(self, signum: int):
        import signal

        super().__init__(signum)
        self.signum = int(signum)
        self.name = signal.Signals(signum).name


def _stop_child(proc, grace: float = 10.0) -> None:
    """End ``proc``: SIGTERM, then SIGKILL after ``grace`` seconds."""
    if proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(timeout=grace)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def _run_child(command, env) -> int:
    """Run ParaView (or pvpython) to its end and return its exit code; if this process is stopped meanwhile
    (SIGTERM, SIGHUP, Ctrl-C), the child is stopped too instead of being left running (SIGTERM / SIGHUP then
    raise :class:`_Stopped`, Ctrl-C KeyboardInterrupt)."""
    import signal
    import threading

    proc = subprocess.Popen(command, env=env)

    def stop(signum, frame):  # runs inside proc.wait(), which holds the Popen's lock: only signal, wait below
        proc.send_signal(signal.SIGTERM)
        raise _Stopped(signum)

    handled = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGTERM, getattr(signal, "SIGHUP", None)):
            if sig is not None:
                handled[sig] = signal.signal(sig, stop)
    try:
        return proc.wait()
    except BaseException:
        _stop_child(proc)
        raise
    finally:
        for sig, old in handled.items():
            signal.signal(sig, old)


def _finish(args, report, rc, exe, converted) -> int:
    if report is None:
        return fail(f"{exe} exited with code {rc} before the hexsos start-up script ran"
                    + ("" if rc else " (was it closed at once?)"))
    if report.get("error"):
        return fail(report["error"])
    if args.script:
        return rc
    if rc != 0:
        return fail(f"{exe} exited with code {rc}")
    meshes = report.get("meshes", [])
    failed = [m["error"] for m in meshes if m.get("error")]
    checked = [m for m in meshes if not m.get("error")]
    code = 2 if failed else 0 if all(m["invalid"] == 0 and m["undecided"] == 0 for m in checked) else 1
    if not args.exit_after and code == 1:
        code = 0
    if args.json:
        print(json.dumps(dict(report, paraview=exe, converted=converted, exit_code=code)))
    else:
        for m in checked:
            extra = f", {m['not_checked']} not checked" if m.get("not_checked") else ""
            mirrored = f"; {m['mirrored']} written in the mirrored node order (blue)" if m.get("mirrored") else ""
            print(f"{m['file']}: {m['cells']} cells: {m['valid']} valid, {m['invalid']} invalid "
                  f"({m['invalid_inside_only']} inside only), {m['undecided']} undecided{extra}; "
                  f"{m['fold_points']} fold points shown{mirrored}")
        if report.get("screenshot"):
            print(f"wrote {report['screenshot']}")
    for error in failed:
        fail(error)
    return code


def _print_env() -> int:
    folder = _vtk_filter_dir()
    print(f"# hexsos in a ParaView started by hand: packages of {sys.executable} (Python {_python_version()});")
    print(f"# ParaView's Python must be {_minor(_python_version())} too (compiled dependencies such as clarabel)")
    print(f"export PV_PLUGIN_PATH={folder}")
    print(f"export HEXSOS_PYTHONPATH={os.pathsep.join(environment_paths())}")
    print("# Debian's ParaView 5.11 with Python >= 3.11 only:")
    print(f"export PYTHONPATH={os.path.join(folder, 'paraview_compat')}${{PYTHONPATH:+:$PYTHONPATH}}")
    return 0


# ----------------------------------------------------------------------------------------------------
# The parsers
# ----------------------------------------------------------------------------------------------------


def _add_paraview(sub):
    p = sub.add_parser(
        "paraview", help="open MESH in ParaView with 'HexSOS Check' applied (the plugin loaded, nothing to set up)",
        description="Start ParaView with the hexsos plugin loaded and this Python's packages found, open each MESH, "
                    "apply 'HexSOS Check' and show it coloured by hexsos_status (valid translucent, invalid red, "
                    "undecided orange) with the fold points (black: where each invalid cell folds). Returns when "
                    "ParaView closes. Exit codes: 0 (with --exit-after: every checked cell proven valid), 1 some "
                    "cell invalid or undecided (--exit-after), 2 error (ParaView missing, Python versions differ, "
                    "unreadable MESH); with --script, the script's exit code.")
    p.add_argument("meshes", nargs="*", metavar="MESH",
                   help="mesh files: .vtu/.pvtu opened by ParaView, any other format hexsos reads (.vtk .msh .mesh "
                        "...) converted to a temporary .vtu first; with --script, the script's arguments")
    p.add_argument("--paraview", metavar="EXE", help="the ParaView executable (default: paraview on PATH)")
    p.add_argument("--pvpython", metavar="EXE",
                   help="ParaView's Python (default: pvpython beside the paraview executable, else on PATH)")
    p.add_argument("--script", metavar="PY",
                   help="run PY in pvpython (batch, off-screen) with the plugin loaded (paraview.simple.HexSOSCheck) "
                        "and MESH... as sys.argv[1:], instead of the GUI")
    p.add_argument("--screenshot", metavar="PNG",
                   help=f"save the view as PNG ({SCREENSHOT_SIZE[0]}x{SCREENSHOT_SIZE[1]}) once the meshes are shown")
    p.add_argument("--exit-after", action="store_true",
                   help="close ParaView once the meshes are checked (and the screenshot saved); exit 0 if every "
                        "checked cell is proven valid, else 1")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object (counts per mesh, the plugin and kernel files ParaView loaded)")
    p.add_argument("--print-env", action="store_true",
                   help="print the environment lines to start ParaView by hand with the plugin "
                        "(PV_PLUGIN_PATH, HEXSOS_PYTHONPATH) and exit")
    p.set_defaults(func=_cmd_paraview)


def _add_gmsh(sub):
    from gmsh_plugin import __main__ as gmsh_door

    p = sub.add_parser("gmsh", help="open MESH in the Gmsh GUI with the hexsos panel (Check, Repair); "
                                    "the same as hexsos-gmsh", description=gmsh_door.DESCRIPTION)
    gmsh_door.add_arguments(p)
    p.set_defaults(func=lambda args: gmsh_door.run(args, prog="hexsos gmsh"))


def add_parsers(sub):
    """Add ``paraview`` and ``gmsh`` to ``sub`` (an ``argparse`` sub-parsers action)."""
    _add_paraview(sub)
    _add_gmsh(sub)
