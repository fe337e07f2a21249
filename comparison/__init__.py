"""The comparison harness of hexsos: cross-checks against dense sampling, Gmsh and VTK, and the paper's
experiments (Marschner et al., SGP 2020), with benchmarks beside them.

    python -m comparison [--quick] [--out DIR] [--meshes DIR] [--jobs N] [--only NAME ...]

runs every experiment (:data:`EXPERIMENTS`, each also runnable alone as ``python -m comparison.<module>``) and
writes ``DIR/report.md``, one PNG per figure and ``DIR/summary.json``. Importing this package imports nothing
heavy.
"""

#: (name in summary.json and --only, module, what it reproduces), in the order they run. ``sampling`` runs
#: before ``recovery``, which reuses its SOS solves (cached in DIR/.cache).
EXPERIMENTS = (
    ("sampling", "sampling", "1. exactness against dense sampling (Figure 8 left)"),
    ("gmsh", "against_gmsh", "2. against Gmsh (Figure 8 right)"),
    ("vtk", "against_vtk", "3. against VTK"),
    ("recovery", "recovery", "4. exact recovery (Figure 5)"),
    ("argmin_locations", "argmin_locations", "5. where the minimum lies (Figure 10), Knupp's conjecture"),
    ("figures_1_2", "figures_1_2", "6. Figures 1 and 2"),
    ("meshes", "meshes", "7. meshes: Figure 9, Table 1"),
    ("cell_types", "cell_types", "8. every cell type against Gmsh and VTK sampling"),
)

__all__ = ["EXPERIMENTS"]
