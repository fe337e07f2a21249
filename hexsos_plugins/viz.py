"""Pictures of a check: the mesh coloured by min det J with invalid cells and their argmin points, and the
histogram of min det J per hex (the paper's Figures 6, 7 and 9). pyvista and matplotlib are imported lazily
(extra ``viz``); rendering is off-screen.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from .errors import DependencyError, MeshWriteError

__all__ = ["screenshot", "histogram", "relative_min_det"]


def relative_min_det(result) -> np.ndarray:
    """min det J divided by the hex's scale (its largest |Bernstein coefficient|, about max |det J|):
    a size-free quality in [-1, 1], 1 for a parallelepiped."""
    scale = np.where(result.scale > 0, result.scale, 1.0)
    return result.min_det / scale


def _pyvista():
    if not os.environ.get("DISPLAY"):
        # without an X server, render through EGL (measured: the default X window warns, OSMesa is absent)
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    try:
        import pyvista as pv
    except ImportError as exc:
        raise DependencyError("pictures need pyvista: pip install 'hexsos[viz]'") from exc
    return pv


def _blocks(cells):
    """[(cell_type, conn)] from an (M, 8) hex array or a list of (cell_type, conn) pairs."""
    if isinstance(cells, (list, tuple)) and cells and isinstance(cells[0], (list, tuple)) and isinstance(cells[0][0], str):
        return [(t, np.asarray(c, dtype=np.int64)) for t, c in cells]
    return [("hexahedron", np.asarray(cells, dtype=np.int64))]


def _grid(pv, points, blocks):
    from .elements import ELEMENTS

    parts, types = [], []
    for t, conn in blocks:
        if t == "pyramid14":  # VTK has no 14-node pyramid: drawn as its 13-node one (base centre left out)
            t, conn = "pyramid13", conn[:, list(ELEMENTS["pyramid13"].gmsh_to_vtk)]
        parts.append(np.hstack([np.full((len(conn), 1), conn.shape[1]), conn]).ravel())
        types.append(np.full(len(conn), ELEMENTS[t].vtk_type, dtype=np.uint8))
    return pv.UnstructuredGrid(np.concatenate(parts), np.concatenate(types), np.asarray(points, float))


def screenshot(points, cells, result, path, *, window_size=(1400, 1000), title: str | None = None) -> str:
    """Render the mesh off-screen to a PNG.

    Valid cells are drawn translucent, coloured by :func:`relative_min_det`; invalid cells opaque (red: a
    corner check would see it too; magenta: invalid inside only, valid at all corners), undecided yellow;
    each invalid cell's minimum location x(argmin) is a black sphere.

    Parameters
    ----------
    points : (N, 3); cells : (M, 8) hexahedra or a list of (cell_type, conn); result : CheckResult of these
    cells; path : PNG file to write

    Returns
    -------
    str, the path written
    """
    pv = _pyvista()
    points = np.asarray(points, float)
    blocks = _blocks(cells)
    grid = _grid(pv, points, blocks)
    rel = relative_min_det(result)
    grid.cell_data["min det J / scale"] = rel
    edges = np.concatenate([np.linalg.norm(points[c[:, 1]] - points[c[:, 0]], axis=1) for _, c in blocks])
    h = float(np.median(edges)) or 1.0

    p = pv.Plotter(off_screen=True, window_size=list(window_size))
    p.set_background("white")
    valid = np.flatnonzero(result.status == 1)
    if valid.size:
        with warnings.catch_warnings():  # pyvista 0.49 announces a change of extract_surface's default
            warnings.simplefilter("ignore")
            surface = grid.extract_cells(valid).extract_surface()
        p.add_mesh(surface, scalars="min det J / scale", cmap="viridis",
                   clim=(min(0.0, float(rel.min())), 1.0), opacity=0.25, show_edges=True, edge_color="gray",
                   scalar_bar_args={"title": "relative min det J", "color": "black", "vertical": True})
    inside = np.flatnonzero(result.invalid_inside_only)
    corner = np.flatnonzero(result.invalid & ~result.invalid_inside_only)
    undecided = np.flatnonzero(result.status == -1)
    for ids, color, opacity, label in ((corner, "red", 0.55, f"invalid ({corner.size})"),
                                       (inside, "magenta", 1.0, f"invalid inside only ({inside.size})"),
                                       (undecided, "gold", 0.8, f"undecided ({undecided.size})")):
        if ids.size:
            p.add_mesh(grid.extract_cells(ids), color=color, opacity=opacity, show_edges=True, edge_color="black",
                       line_width=2, label=label)
    bad = np.flatnonzero(result.status != 1)
    if bad.size:  # (then at least one labelled item exists for the legend)
        from .elements import world_points

        where = world_points(points, blocks, result.argmin)[bad]
        p.add_mesh(pv.PolyData(where).glyph(geom=pv.Sphere(radius=0.18 * h), scale=False, orient=False),
                   color="black", label="where det J is smallest")
        p.add_legend(bcolor="white", face="rectangle", size=(0.28, 0.16), loc="upper left")
    c = result.counts()
    p.add_text(title or f"{c['cells']} cells: {c['invalid']} invalid ({c['invalid_inside_only']} inside only), "
               f"{c['undecided']} undecided", font_size=11, color="black", position="lower_left")
    p.view_isometric()
    p.reset_camera()
    path = os.fspath(path)
    try:
        p.screenshot(path)
    except (OSError, RuntimeError, ValueError) as exc:
        raise MeshWriteError(f"{path}: could not render the screenshot ({exc})") from exc
    finally:
        p.close()
    return path


def histogram(result, path, *, title: str | None = None, bins: int = 60) -> str:
    """Histogram of min det J per hex (relative to each hex's scale), log counts; invalid bins in red."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:
        raise DependencyError("the histogram needs matplotlib: pip install 'hexsos[viz]'") from exc
    rel = relative_min_det(result)
    lo = min(float(rel.min()), 0.0)
    edges = np.linspace(lo - 1e-9, 1.0 + 1e-9, bins + 1)
    counts, edges = np.histogram(np.clip(rel, edges[0], edges[-1]), bins=edges)
    fig, ax = plt.subplots(figsize=(7.5, 4.2), dpi=130)
    colors = ["#d62728" if e <= 0 else "#1f77b4" for e in edges[:-1]]
    ax.bar(edges[:-1], counts, width=np.diff(edges), align="edge", color=colors, edgecolor="white", linewidth=0.3)
    ax.set_yscale("log")
    ax.axvline(0.0, color="black", linewidth=1)
    ax.set_xlabel("min det J / max |det J| per cell  (<= 0: invalid)")
    ax.set_ylabel("cells")
    c = result.counts()
    ax.set_title(title or f"{c['cells']} cells: {c['invalid']} invalid, {c['invalid_inside_only']} of them "
                          "inside only", fontsize=10)
    ax.set_xlim(edges[0], edges[-1])
    fig.tight_layout()
    path = os.fspath(path)
    try:
        fig.savefig(path)
    except OSError as exc:
        raise MeshWriteError(f"{path}: could not write the histogram ({exc.strerror or exc})") from exc
    finally:
        plt.close(fig)
    return path
