"""Pictures of a check and of a repair: the mesh coloured by min det J with invalid cells and their argmin points,
the histogram of min det J per hex (the paper's Figures 6, 7 and 9), a repair's convergence (the paper's Figure 11)
and its scaled Jacobian before and after. pyvista and matplotlib are imported lazily (extra ``viz``); rendering is
off-screen; every file is written atomically or not at all.

Imports :mod:`hexsos_plugins.errors` and the cells wing only: it draws results, it computes none.
"""

from __future__ import annotations

import os
import tempfile
import warnings

import numpy as np

from .errors import DependencyError, MeshWriteError

__all__ = ["screenshot", "histogram", "relative_min_det", "plot_history", "plot_histogram"]


def relative_min_det(result) -> np.ndarray:
    """min det J divided by the hex's scale (its largest |Bernstein coefficient|, about max |det J|):
    a size-free quality in [-1, 1], 1 for a parallelepiped."""
    return result.relative_min_det


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
    """[(cell_type, conn)] from an (M, 8) hex array, a list of (cell_type, conn) pairs, or meshio's cells."""
    from .cells.inputs import cell_pairs

    pairs, _ = cell_pairs(cells)
    cells = pairs if pairs is not None else cells
    if isinstance(cells, (list, tuple)) and cells and isinstance(cells[0], (list, tuple)) and isinstance(cells[0][0], str):
        return [(t, np.asarray(c, dtype=np.int64)) for t, c in cells]
    return [("hexahedron", np.asarray(cells, dtype=np.int64))]


def _grid(pv, points, blocks):
    from .cells.elements import ELEMENTS

    parts, types = [], []
    for t, conn in blocks:
        if t == "pyramid14":  # VTK has no 14-node pyramid: drawn as its 13-node one (base centre left out)
            t, conn = "pyramid13", conn[:, list(ELEMENTS["pyramid13"].gmsh_to_vtk)]
        parts.append(np.hstack([np.full((len(conn), 1), conn.shape[1]), conn]).ravel())
        types.append(np.full(len(conn), ELEMENTS[t].vtk_type, dtype=np.uint8))
    return pv.UnstructuredGrid(np.concatenate(parts), np.concatenate(types), np.asarray(points, float))


#: Most insets a screenshot shows (the largest clusters of cells not proven valid; every cluster is framed).
MAX_INSETS = 3


def bad_clusters(points, blocks, result, h: float) -> list:
    """The cells not proven valid, grouped in clusters of cells whose centres lie within 3 ``h`` (the median
    edge) of each other: ``[ids, ...]``, largest first."""
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    bad = np.flatnonzero(np.asarray(result.status) != 1)
    if bad.size == 0:
        return []
    conn = np.concatenate([np.pad(c, ((0, 0), (0, 27 - c.shape[1])), constant_values=-1) for _, c in blocks])[bad]
    pts = np.where(conn[..., None] >= 0, points[np.maximum(conn, 0)], np.nan)
    centres = np.nanmean(pts, axis=1)
    if bad.size == 1:
        return [bad]
    pairs = cKDTree(centres).query_pairs(3.0 * h, output_type="ndarray")
    from scipy.sparse import coo_matrix

    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(bad.size, bad.size))
    _, label = connected_components(graph, directed=False)
    groups = [bad[label == k] for k in range(label.max() + 1)]
    return sorted(groups, key=lambda g: (-g.size, int(g[0])))


def _cluster_box(grid, ids, least: float):
    """The bounds of the cells ``ids``, grown to at least ``least`` per side around their centre."""
    b = np.asarray(grid.extract_cells(ids).bounds, dtype=float).reshape(3, 2)
    centre, half = b.mean(axis=1), np.maximum((b[:, 1] - b[:, 0]) / 2 * 1.3, least / 2)
    return np.column_stack([centre - half, centre + half]).ravel()


def screenshot(points, cells, result, path, *, window_size=(1400, 1000), title: str | None = None) -> str:
    """Render the mesh off-screen to a PNG.

    Valid cells are drawn translucent, coloured by :func:`relative_min_det`; invalid cells opaque (red: a
    corner check would see it too; magenta: invalid inside only, valid at all corners), undecided yellow;
    each invalid cell's minimum location x(argmin) is a black sphere.

    However small the cells not proven valid are beside the whole mesh, they are seen: each cluster of them
    (:func:`bad_clusters`) smaller than a tenth of the mesh's diagonal is framed in the main view by a box of at
    least 6% of the diagonal, and the largest of those (up to :data:`MAX_INSETS`) get an inset of their own on
    the right, zoomed on the cluster and its neighbours, numbered as their frames.

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
    diag = float(np.linalg.norm(np.ptp(points[np.unique(np.concatenate([c.ravel() for _, c in blocks]))], axis=0)))
    diag = diag or h

    # clusters too small to be seen at the mesh's scale (under a tenth of its diagonal): framed, and insets
    # for the largest of them
    clusters = [ids for ids in bad_clusters(points, blocks, result, h)
                if np.linalg.norm(np.ptp(np.asarray(grid.extract_cells(ids).bounds).reshape(3, 2), axis=1))
                < 0.1 * diag]
    boxes = [_cluster_box(grid, ids, 0.06 * diag) for ids in clusters]
    zoomed = list(range(min(len(clusters), MAX_INSETS)))
    shape = f"1|{len(zoomed)}" if zoomed else (1, 1)
    kwargs = {"splitting_position": 0.72} if zoomed else {}
    p = pv.Plotter(off_screen=True, window_size=list(window_size), shape=shape, border=bool(zoomed), **kwargs)
    p.set_background("white")
    if zoomed:
        p.subplot(0)
    _draw(pv, p, grid, points, blocks, result, rel, h, legend=True)
    for k, (ids, bx) in enumerate(zip(clusters, boxes)):
        colour = "magenta" if np.asarray(result.invalid_inside_only)[ids].all() else \
            "red" if np.asarray(result.invalid)[ids].any() else "gold"
        p.add_mesh(pv.Box(bounds=bx).extract_all_edges(), color=colour, line_width=3)
        if k in zoomed:
            p.add_point_labels(np.asarray(bx[1::2])[None], [str(zoomed.index(k) + 1)], font_size=16,
                               text_color="black", shape_color="white", point_size=1, always_visible=True)
    c = result.counts()
    p.add_text(title or f"{c['cells']} cells: {c['invalid']} invalid ({c['invalid_inside_only']} inside only), "
               f"{c['undecided']} undecided", font_size=11, color="black", position="lower_left")
    p.view_isometric()
    p.reset_camera()
    for j, k in enumerate(zoomed):
        p.subplot(j + 1)
        p.set_background("white")
        ids = clusters[k]
        own = np.asarray(grid.extract_cells(ids).bounds, dtype=float)  # the cluster and a ring of cells around it
        lo, hi = own[::2] - 1.5 * h, own[1::2] + 1.5 * h
        centres = grid.cell_centers().points
        near = np.flatnonzero(np.all((centres >= lo) & (centres <= hi), axis=1))
        _draw(pv, p, grid.extract_cells(near), points, blocks, result, rel, h, only=near)
        n_inv = int(np.asarray(result.invalid)[ids].sum())
        n_und = int((np.asarray(result.status)[ids] == -1).sum())
        p.add_text(f"{j + 1}: {n_inv} invalid" + (f", {n_und} undecided" if n_und else ""), font_size=10,
                   color="black", position="upper_left")
        p.view_isometric()
        p.reset_camera(bounds=tuple(np.column_stack([lo, hi]).ravel()))
    path = os.fspath(path)
    try:
        p.screenshot(path)
    except (OSError, RuntimeError, ValueError) as exc:
        raise MeshWriteError(f"{path}: could not render the screenshot ({exc})") from exc
    finally:
        p.close()
    return path


def _draw(pv, p, grid, points, blocks, result, rel, h, *, legend=False, only=None):
    """The cells of ``grid`` (all the result's cells, or the result's cells ``only`` in that order) on the
    current renderer of ``p``: valid translucent, the others opaque by kind, spheres at the argmin points."""
    ids_all = np.arange(len(result)) if only is None else np.asarray(only)
    status = np.asarray(result.status)[ids_all]
    inside_all = np.asarray(result.invalid_inside_only)[ids_all]
    invalid_all = np.asarray(result.invalid)[ids_all]
    valid = np.flatnonzero(status == 1)
    if valid.size:
        with warnings.catch_warnings():  # pyvista 0.49 announces a change of extract_surface's default
            warnings.simplefilter("ignore")
            surface = grid.extract_cells(valid).extract_surface()
        kw = {"scalar_bar_args": {"title": "relative min det J", "color": "black", "vertical": True,
                                  "position_x": 0.84, "position_y": 0.08, "width": 0.06, "height": 0.45,
                                  "title_font_size": 14, "label_font_size": 12}} if legend \
            else {"show_scalar_bar": False}
        p.add_mesh(surface, scalars="min det J / scale", cmap="viridis",
                   clim=(min(0.0, float(rel.min())), 1.0), opacity=0.25, show_edges=True, edge_color="gray", **kw)
    inside = np.flatnonzero(inside_all)
    corner = np.flatnonzero(invalid_all & ~inside_all)
    undecided = np.flatnonzero(status == -1)
    for ids, color, opacity, label in ((corner, "red", 0.55, f"invalid ({corner.size})"),
                                       (inside, "magenta", 1.0, f"invalid inside only ({inside.size})"),
                                       (undecided, "gold", 0.8, f"undecided ({undecided.size})")):
        if ids.size:
            p.add_mesh(grid.extract_cells(ids), color=color, opacity=opacity, show_edges=True, edge_color="black",
                       line_width=2, label=label if legend else None)
    bad = np.flatnonzero(status != 1)
    if bad.size:
        from .cells.elements import world_points

        where = world_points(points, blocks, np.asarray(result.argmin))[ids_all[bad]]
        p.add_mesh(pv.PolyData(where).glyph(geom=pv.Sphere(radius=0.18 * h), scale=False, orient=False),
                   color="black", label="where det J is smallest" if legend else None)
        if legend:
            p.add_legend(bcolor="white", face="rectangle", size=(0.28, 0.16), loc="upper left")


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


def _figure():
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg  # no pyplot: no global backend switch
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise DependencyError("--plot / --histogram need matplotlib: pip install 'hexsos[viz]'") from exc
    fig = Figure(figsize=(6.4, 4.0), dpi=120)
    FigureCanvasAgg(fig)
    return fig


def _save(fig, path):
    directory = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(directory):
        raise MeshWriteError(f"{path}: cannot write the plot, the directory {directory} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=".hexsos-plot.", suffix=".png", dir=directory)
    os.close(fd)
    try:
        fig.savefig(tmp, format="png")
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise
    return path


def plot_history(history, path, *, title: str | None = None) -> str:
    """Write the convergence plot (the paper's Figure 11, plus the scaled Jacobian) as a PNG, atomically.

    Cells not proven valid per step on the left y-axis; the smallest min det J over the mesh and, when the
    history has it, the smallest scaled Jacobian on the right. Needs matplotlib (extra ``viz``); Agg backend.
    """
    it = [h["iteration"] for h in history]
    bad = [h["invalid"] + h.get("undecided", 0) + h.get("other_invalid", 0) for h in history]
    md = [h["min_det"] for h in history]
    fig = _figure()
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(it, bad, "-o", color="tab:blue", markersize=3, label="cells not proven valid")
    ax.set_xlabel("outer step" if "stage" in history[-1] else "outer iteration (Algorithm 2)")
    ax.set_ylabel("cells not proven valid", color="tab:blue")
    ax.tick_params(axis="y", labelcolor="tab:blue")
    ax.set_ylim(bottom=0)
    ax2 = ax.twinx()
    ax2.plot(it, md, "-s", color="tab:red", markersize=3, label="min det J")
    if all("min_sj" in h for h in history):
        ax2.plot(it, [h["min_sj"] for h in history], "-^", color="tab:green", markersize=3,
                 label="min scaled Jacobian")
        ax2.set_ylabel("min det J (red), min scaled Jacobian (green)")
        ax2.legend(loc="lower right", fontsize=8)
    else:
        ax2.set_ylabel("min det J over the mesh", color="tab:red")
    ax2.axhline(0.0, color="tab:red", linewidth=0.6, linestyle=":")
    ax2.tick_params(axis="y", labelcolor="tab:red")
    ax.set_title(f"hexsos repair{': ' + title if title else ''}")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return _save(fig, path)


def plot_histogram(before, after, path, *, title: str | None = None) -> str:
    """Write the histogram of the scaled Jacobian per cell before and after the repair as a PNG, atomically."""
    b = np.asarray(before, dtype=np.float64)
    a = np.asarray(after, dtype=np.float64)
    b, a = b[np.isfinite(b)], a[np.isfinite(a)]
    fig = _figure()
    ax = fig.add_subplot(1, 1, 1)
    bins = np.linspace(min(-1.0, float(b.min()) if b.size else -1.0), 1.0, 81)
    ax.hist(b, bins=bins, alpha=0.55, color="tab:red", label=f"before (min {b.min():.3f})" if b.size else "before")
    ax.hist(a, bins=bins, alpha=0.55, color="tab:blue", label=f"after (min {a.min():.3f})" if a.size else "after")
    ax.set_yscale("log")
    ax.set_xlabel("scaled Jacobian (Verdict, corners)")
    ax.set_ylabel("cells")
    ax.axvline(0.0, color="k", linewidth=0.6, linestyle=":")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(f"hexsos repair{': ' + title if title else ''}")
    fig.tight_layout()
    return _save(fig, path)
