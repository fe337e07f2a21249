"""Run every experiment of the comparison harness and write report.md, the pictures and summary.json.

    python -m comparison [--quick] [--out DIR] [--meshes DIR ...] [--jobs N] [--only NAME ...]
"""

from __future__ import annotations

from comparison import common as C  # first: one BLAS thread per process

import argparse  # noqa: E402
import importlib  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from pathlib import Path  # noqa: E402

from comparison import EXPERIMENTS  # noqa: E402


def seeds() -> dict:
    from comparison import against_gmsh, against_vtk, argmin_locations, sampling

    return {
        "sampling (exp. 1) and recovery (exp. 4)": f"random_hexes(sigma={sampling.SIGMA}, seed={sampling.SEED})",
        "gmsh (exp. 2)": ", ".join(f"{k}: seed {v}" for k, v in against_gmsh.SEEDS.items()),
        "vtk (exp. 3)": ", ".join(f"sigma {k}: seed {v}" for k, v in against_vtk.SEEDS.items()),
        "argmin_locations (exp. 5)": ", ".join(f"sigma {k}: seed {v}" for k, v in argmin_locations.SEEDS.items())
        + f"; search sigma {argmin_locations.SEARCH['sigma']}: seed {argmin_locations.SEARCH['seed']}",
        "figures_1_2 (exp. 6)": "deterministic (no random numbers)",
        "meshes (exp. 7)": "deterministic (repair has no random numbers)",
        "cell_types (exp. 8)": "seed [8, type index] (random cells), [8, 100 + type index] (moved mesh nodes)",
    }


def _key_line(name, s):
    """One line per experiment for the overview table."""
    try:
        if name == "sampling":
            x = s["sampling"]
            return (f"{x['hexes']:,} hexes: max abs diff {x['max_abs_diff']:.1e} (paper's recipe), "
                    f"{x['max_abs_diff_closed_grid']:.1e} (closed grids); dense < lower bound: {x['dense_below_lower_bound']}")
        if name == "gmsh":
            x = s["gmsh"]
            return (f"{x['hexes']:,} hexes: sign disagreements {x['sign_disagreements']}, max gap {x['max_gap']:.1e}, "
                    f"throughput ratio {x['throughput_ratio']:.2f}")
        if name == "vtk":
            x = s["vtk"]
            return (f"{x['hexes']:,} hexes: VTK misses {x['missed']:,} of {x['invalid']:,} invalid, false alarms "
                    f"{x['false_alarms']}, misses inside_invalid_hex(): {x['misses_inside_invalid_hex']}")
        if name == "recovery":
            x = s["recovery"]
            deg = "; ".join(f"degree {d}: max {v['max']:.1e} ({v['hexes']} hexes)" for d, v in x["degrees"].items()
                            if v["max"] is not None)
            w = x["whole_sample"]["paper"]
            return f"{deg}; whole sample ({w['hexes']:,}): max {w['max']:.1e}"
        if name == "argmin_locations":
            x, k = s["argmin_locations"], s["knupp"]
            return ("interior minima " + ", ".join(f"sigma {sg}: {c['interior']}" for sg, c in x.items())
                    + f"; positive on all faces but invalid: {k['faces_positive_but_invalid']}")
        if name == "figures_1_2":
            x = s["figures_1_2"]
            f2 = x["figure2"]
            return (f"twist invalid inside only from {x['figure1']['first_invalid_deg']:.0f} deg; ball: "
                    f"{f2['inside_only']:,} inside-only, {f2['corner_invalid']:,} corner-invalid of {f2['positions']:,}")
        if name == "cell_types":
            x = s["cell_types"]
            return (f"{x['cells']:,} cells of 9 types: sign disagreements with Gmsh {x['sign_disagreements']}, Gmsh "
                    f"above ours {x['gmsh_above_ours']}, sampled below our bound {x['sampled_below_lower']}, max "
                    f"bracket {x['max_bracket']:.1e}")
        if name == "meshes":
            x = s["meshes"]
            return "; ".join(f"{m['mesh']}: {m['invalid']} invalid of {m['hexes']:,}" for m in x["meshes"]) or "no mesh"
    except Exception as exc:  # noqa: BLE001
        return f"(summary unavailable: {exc})"
    return ""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    C.add_common_args(ap)
    ap.add_argument("--meshes", nargs="*", default=None,
                    help="mesh files or directories for experiment 7 (default: ../shared/data/bunny.vtk if present)")
    names = [n for n, _, _ in EXPERIMENTS]
    ap.add_argument("--only", nargs="+", metavar="NAME", help=f"run only these experiments: {', '.join(names)}")
    args = ap.parse_args(argv)
    mods = {n: m for n, m, _ in EXPERIMENTS}
    mods.update({m: m for _, m, _ in EXPERIMENTS})
    todo = names
    if args.only:
        bad = [n for n in args.only if n not in mods]
        if bad:
            ap.error(f"unknown experiment(s) {bad}: expected some of {names}")
        wanted = {mods[n] for n in args.only}
        todo = [n for n, m, _ in EXPERIMENTS if m in wanted]
    size = "tiny" if args.tiny else ("quick" if args.quick else "full")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    C.log(f"{size} run of {', '.join(todo)} into {out} with {args.jobs} job(s)")
    results, errors = [], {}
    for n in todo:
        mod = importlib.import_module(f".{mods[n]}", __package__)
        kw = {"meshes": args.meshes} if n == "meshes" else {}
        C.log(f"== {n} ==")
        try:
            res = mod.run(quick=args.quick, out=out, jobs=args.jobs, size=size, **kw)
            results.append(res)
            C.log(f"{n}: {res['seconds']} s")
        except Exception as exc:  # noqa: BLE001 - one failing experiment must not lose the others
            errors[n] = f"{type(exc).__name__}: {exc}"
            C.log(f"{n} FAILED: {errors[n]}\n{traceback.format_exc()}")
    wall = time.perf_counter() - t0

    versions = C.versions()
    summary = {"size": size, "quick": size == "quick", "jobs": args.jobs, "wall_seconds": round(wall, 1),
               "command": "python -m comparison " + " ".join(sys.argv[1:] if argv is None else argv),
               "versions": versions, "seeds": seeds(), "experiments": {r["name"]: r["seconds"] for r in results},
               "figures": [f for r in results for f in r["figures"]], "errors": errors}
    for r in results:
        summary.update(r["summary"])
    (out / "summary.json").write_text(json.dumps(C.jsonable(summary), indent=2) + "\n")

    md = [f"# hexsos comparison report ({size} run)", "",
          f"`{summary['command']}`: {len(results)} experiment(s) in {wall:.0f} s wall time on {os.cpu_count()} CPUs "
          f"with {args.jobs} worker process(es) (`--quick`: minutes; without it, the paper's sizes).", ""]
    md.append(C.table(["experiment", "key figures", "seconds"],
                      [[r["title"], _key_line(r["name"], r["summary"]), r["seconds"]] for r in results]
                      + [[n, f"FAILED: {e}", None] for n, e in errors.items()],
                      "What each experiment found, in one line (details in its section below)."))
    def _sz(d):
        return ", ".join(f"{k} " + (", ".join(f"{kk}: {vv}" for kk, vv in v.items()) if isinstance(v, dict)
                                     else (f"{v:,}" if isinstance(v, int) else str(v))) for k, v in d.items())

    md.append(C.table(["experiment", "this run's sizes", "the paper's"],
                      [[r["title"].split(" (")[0], _sz(importlib.import_module(f".{mods[r['name']]}", __package__)
                                                     .SIZES[size]),
                        importlib.import_module(f".{mods[r['name']]}", __package__).PAPER_SIZE] for r in results],
                      "The sizes of this run beside the paper's (the quick run keeps >= 1000 hexes per experiment "
                      "except for the degree-6 and degree-8 relaxations of experiment 4, which cost 0.2 and 3-8 s per hex)."))
    md.append(C.table(["package", "version"], [[k, v] for k, v in versions.items()],
                      "The software the numbers come from."))
    md.append(C.table(["experiment", "random hexes"], [[k, v] for k, v in seeds().items()],
                      "The fixed seeds (numpy.random.default_rng) of every random sample."))
    for r in results:
        md += [f"## {r['title']}", "", r["markdown"].strip(), ""]
    (out / "report.md").write_text("\n".join(md) + "\n")
    C.log(f"wrote {out / 'report.md'} and {out / 'summary.json'} in {wall:.0f} s"
          + (f"; FAILED: {', '.join(errors)}" if errors else ""))
    return 1 if errors else 0


if __name__ == "__main__":
    raise SystemExit(main())
