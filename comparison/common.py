"""Shared plumbing of the comparison harness: sizes, progress, process pools, tables, figures, versions.

Every experiment module ``comparison.<name>`` has ``run(quick=False, out=..., jobs=1, *, size=None, ...)``
returning a dict::

    {"name": str, "title": str, "summary": {top-level summary.json keys: ...},
     "markdown": str (the report section), "figures": [PNG file names in out], "seconds": float}

and a ``main(argv)`` (``python -m comparison.<name> [--quick|--tiny] [--out DIR] [--jobs N]``) that writes
``DIR/<name>.md`` and ``DIR/<name>.json`` beside its pictures. ``python -m comparison`` runs them all and
writes ``DIR/report.md`` and ``DIR/summary.json``.
"""

from __future__ import annotations

import os

# one BLAS thread per process: the harness spreads work over processes itself (--jobs), and the machine is
# shared. Set before numpy is imported where possible; spawned workers inherit the environment.
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import multiprocessing  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ProcessPoolExecutor, as_completed  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

SIZES = ("tiny", "quick", "full")
_T0 = time.perf_counter()


def resolve_size(quick: bool, size: str | None) -> str:
    """``size`` wins when given; else ``"quick"`` or ``"full"`` by ``quick``."""
    if size is None:
        return "quick" if quick else "full"
    if size not in SIZES:
        raise ValueError(f"size: expected one of {SIZES}, found {size!r}")
    return size


def log(msg: str) -> None:
    """Progress on stderr, stamped with the seconds since the harness started."""
    print(f"[comparison {time.perf_counter() - _T0:7.1f}s] {msg}", file=sys.stderr, flush=True)


# --- process pools ------------------------------------------------------------------------------------------


def chunks(n: int, jobs: int, *, per_job: int = 8, min_size: int = 1, max_size: int | None = None):
    """Split range(n) into contiguous (start, stop) chunks: about ``per_job`` chunks per worker."""
    if n <= 0:
        return []
    k = max(1, jobs) * per_job
    size = max(min_size, math.ceil(n / k))
    if max_size is not None:
        size = min(size, max_size)
    return [(s, min(s + size, n)) for s in range(0, n, size)]


def pmap(fn, args_list, jobs: int, *, desc: str = "", total: int | None = None, weights=None):
    """``[fn(*args) for args in args_list]``, over ``jobs`` processes when ``jobs > 1``, in order.

    Each task's arguments should be small (a chunk of hex coordinates, a few numbers): nothing big is
    pickled per task. Progress (``weights`` per task, e.g. hexes; default 1) goes to stderr. Workers are
    *spawned* (not forked): safe whatever the parent has loaded (Gmsh, VTK, BLAS threads).
    """
    args_list = list(args_list)
    weights = list(weights) if weights is not None else [1] * len(args_list)
    total = sum(weights) if total is None else total
    done, last = 0, time.perf_counter()
    results = [None] * len(args_list)
    if jobs <= 1 or len(args_list) <= 1:
        for i, a in enumerate(args_list):
            results[i] = fn(*a)
            done += weights[i]
            if desc and (time.perf_counter() - last > 5 or i == len(args_list) - 1):
                log(f"{desc}: {done}/{total}")
                last = time.perf_counter()
        return results
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=min(jobs, len(args_list)), mp_context=ctx) as ex:
        futs = {ex.submit(fn, *a): i for i, a in enumerate(args_list)}
        for f in as_completed(futs):
            i = futs[f]
            results[i] = f.result()
            done += weights[i]
            if desc and (time.perf_counter() - last > 5 or done == total):
                log(f"{desc}: {done}/{total}")
                last = time.perf_counter()
    return results


def check_chunk(X, kw):
    """Worker: ``hexsos_plugins.check`` on separate hexes X (m, 8, 3) with keywords kw."""
    from hexsos_plugins import check
    from hexsos_plugins.examples import hexes_to_mesh

    return check(*hexes_to_mesh(X), **kw)


def check_hexes(X, jobs: int = 1, *, desc: str = "", per_job: int = 8, **kw):
    """``check`` on separate hexes X (M, 8, 3), chunks spread over ``jobs`` processes; one CheckResult.

    ``seconds`` of the result is the wall time of the whole call.
    """
    from hexsos_plugins.certify import CheckResult

    t = time.perf_counter()
    X = np.asarray(X, dtype=np.float64)
    parts = chunks(X.shape[0], jobs, per_job=per_job)
    res = pmap(check_chunk, [(X[a:b], kw) for a, b in parts], jobs, desc=desc, weights=[b - a for a, b in parts])
    r = CheckResult.concatenate(res) if len(res) > 1 else res[0]
    r.seconds = time.perf_counter() - t
    return r


# --- tables, numbers ----------------------------------------------------------------------------------------


def fmt(x, digits: int = 3) -> str:
    """A number for a Markdown table: ints with separators, floats in %.{digits}g, None as '-'."""
    if x is None:
        return "-"
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return f"{int(x):,}"
    if isinstance(x, (float, np.floating)):
        x = float(x)
        if math.isnan(x):
            return "n/a"
        if x == 0:
            return "0"
        if 1e3 <= abs(x) < 1e12:
            return f"{x:,.0f}"
        return f"{x:.{digits}g}"
    return str(x)


def table(header, rows, sentence: str) -> str:
    """A Markdown table preceded by the one sentence that says what it shows."""
    esc = lambda c: fmt(c).replace("|", "\\|")  # noqa: E731 - a literal | would end the cell
    lines = [sentence.strip(), "", "| " + " | ".join(esc(h) for h in header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        lines.append("| " + " | ".join(esc(c) for c in r) + " |")
    return "\n".join(lines) + "\n"


def jsonable(obj):
    """Plain JSON types from numpy scalars/arrays (NaN and inf become None)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        x = float(obj)
        return x if math.isfinite(x) else None
    return obj


# --- figures ------------------------------------------------------------------------------------------------


def pyplot():
    """matplotlib.pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, out: Path, name: str) -> str:
    """Save a figure as ``out/name`` (PNG, 120 dpi) and close it; returns the file name."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / name, dpi=120, bbox_inches="tight")
    pyplot().close(fig)
    return name


# --- versions -----------------------------------------------------------------------------------------------


def versions() -> dict:
    """Versions of the software the numbers depend on (None where a package is missing)."""
    v = {"python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count()}

    def get(name, fn):
        try:
            v[name] = fn()
        except Exception:  # noqa: BLE001 - a missing optional package is reported as None
            v[name] = None

    def _hexsos():
        import hexsos_plugins

        return hexsos_plugins.__version__

    def _mod(m):
        return lambda: __import__(m).__version__

    def _vtk():
        from vtkmodules.vtkCommonCore import vtkVersion

        return vtkVersion.GetVTKVersion()

    get("hexsos", _hexsos)
    for m in ("numpy", "scipy", "clarabel", "gmsh", "meshio", "matplotlib", "pyvista"):
        get(m, _mod(m))
    get("vtk", _vtk)
    return v


# --- standalone entry point of an experiment ----------------------------------------------------------------


def result(name, title, summary, markdown, figures, t0) -> dict:
    return {"name": name, "title": title, "summary": jsonable(summary), "markdown": markdown,
            "figures": list(figures), "seconds": round(time.perf_counter() - t0, 2)}


def write_experiment(res: dict, out: Path) -> None:
    """``out/<name>.md`` and ``out/<name>.json`` for one experiment."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{res['name']}.md").write_text(f"## {res['title']}\n\n{res['markdown']}\n")
    (out / f"{res['name']}.json").write_text(json.dumps(jsonable(res["summary"]), indent=2) + "\n")


def add_common_args(ap: argparse.ArgumentParser) -> None:
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--quick", action="store_true", help="the quick sizes (minutes), else the paper's sizes")
    g.add_argument("--tiny", action="store_true", help="tiny sizes (seconds), for tests")
    ap.add_argument("--out", default="comparison-out", help="output directory (default: comparison-out)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                    help="worker processes for the per-hex work (default: all CPUs)")


def standalone(module_run, doc: str, argv=None, extra=None) -> int:
    """``python -m comparison.<name>``: parse the common options, run, write <name>.md/.json."""
    ap = argparse.ArgumentParser(description=doc.strip().splitlines()[0])
    add_common_args(ap)
    if extra is not None:
        extra(ap)
    args = ap.parse_args(argv)
    kw = {k: v for k, v in vars(args).items() if k not in ("quick", "tiny", "out", "jobs")}
    size = "tiny" if args.tiny else None
    res = module_run(quick=args.quick, out=args.out, jobs=args.jobs, size=size, **kw)
    write_experiment(res, args.out)
    log(f"{res['name']}: done in {res['seconds']} s; wrote {Path(args.out) / (res['name'] + '.md')}")
    print(res["markdown"])
    return 0


# --- a small cache: SOS solves shared between experiments run into the same output directory ---------------

_RESULT_ARRAYS = ("min_det", "lower_bound", "argmin", "status", "corner_min_det", "method", "recovery_ratio",
                  "sos_status", "scale")


def cached_check(X, out, jobs: int = 1, *, desc: str = "", **kw):
    """:func:`check_hexes`, remembered in ``out/.cache`` under a hash of the hexes and the keywords.

    The SOS runs of experiment 1 (every hex, both relaxations) are the degree-4 sample of experiment 4:
    run into the same directory, the second one reuses them. Returns (CheckResult, reused: bool).
    """
    import hashlib

    from hexsos_plugins.certify import CheckResult

    import hexsos_plugins

    X = np.ascontiguousarray(X, dtype=np.float64)
    h = hashlib.sha1(X.tobytes())
    h.update(json.dumps(kw, sort_keys=True).encode())
    # a changed kernel must not reuse old results: key on the kernel's source files too
    src = Path(hexsos_plugins.__file__).parent
    for f in ("certify/pipeline.py", "kernel/sos.py", "kernel/calls.py", "kernel/cell_tables.py", "kernel/source.py",
              "kernel/generated.py", "kernel/exact.py", "cells/jacobian.py", "cells/elements.py", "cells/hexahedron.py"):
        if (src / f).exists():
            h.update((src / f).read_bytes())
    path = Path(out) / ".cache" / f"check-{h.hexdigest()[:16]}.npz"
    if path.exists():
        try:
            z = np.load(path)
            r = CheckResult(**{k: z[k] for k in _RESULT_ARRAYS}, seconds=float(z["seconds"]),
                            method_requested=str(z["method_requested"]), relaxation=str(z["relaxation"]),
                            sos_solves=int(z["sos_solves"]), boxes=int(z["boxes"]))
            log(f"{desc}: reused {path}")
            return r, True
        except Exception:  # noqa: BLE001 - a broken cache file is recomputed
            pass
    r = check_hexes(X, jobs, desc=desc, **kw)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **{k: getattr(r, k) for k in _RESULT_ARRAYS}, seconds=r.seconds,
             method_requested=r.method_requested, relaxation=r.relaxation, sos_solves=r.sos_solves, boxes=r.boxes)
    os.replace(tmp, path)
    return r, False
