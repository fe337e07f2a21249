"""Writing Gmsh MSH 4.1 (binary), a file both Gmsh and meshio 5.3.5 read back with every block, tag and array.

Why not meshio's writers: its MSH 2.2 files with ``$ElementData`` over more than one cell block are unreadable by
its own 2.2 reader (it splits the data at the length of a ``(type, data)`` tuple, 2, instead of the block's), and
its MSH 4.1 writer needs ``gmsh:dim_tags`` point data and keeps one physical tag per block. This writer:

* one entity per run of consecutive cells of one block with the same ``(gmsh:geometrical, gmsh:physical)``
  (the entity's tag is the geometrical tag when that tag names one physical tag in its dimension, else a fresh
  one); so the file's elements, element tags (1..N) and ``$ElementData`` stay in the mesh's order, and each
  element keeps its physical tag (MSH 4 attaches physical tags to entities, not elements);
* nodes with tags 1..N in the mesh's order (meshio returns points in file order), one ``$Nodes`` block per run of
  nodes on one entity of ``gmsh:dim_tags`` (what Gmsh and meshio's MSH 4 reader give), else one block on the first
  entity of the highest dimension;
* ``$PhysicalNames`` from ``[tag, dim]`` field data; ``$NodeData`` / ``$ElementData`` as MSH 2.2 (unchanged in 4.1).

Called by :func:`hexsos_plugins.writers.write` on a mesh already prepared for MSH (integer tags, data of 1, 3 or 9
components, blocks in the order meshio's Gmsh writer expects).
"""

from __future__ import annotations

import numpy as np

__all__ = ["write_msh41"]


def _gmsh_tables():
    from meshio.gmsh.common import _meshio_to_gmsh_order, _meshio_to_gmsh_type

    return _meshio_to_gmsh_type, _meshio_to_gmsh_order


def _dims():
    from meshio._mesh import topological_dimension

    return topological_dimension


def _runs(values: np.ndarray):
    """(start, stop) of the runs of equal rows of ``values`` (n, k)."""
    n = len(values)
    if n == 0:
        return []
    change = np.flatnonzero(np.any(values[1:] != values[:-1], axis=1)) + 1
    bounds = np.concatenate([[0], change, [n]])
    return list(zip(bounds[:-1].tolist(), bounds[1:].tolist()))


def _entities(mesh):
    """Element runs (block, start, stop, dim, entity tag) and entities {(dim, tag): physical tag or 0}."""
    to_type, _ = _gmsh_tables()
    topo = _dims()
    runs = []  # (block, start, stop, dim, geometrical, physical)
    for b, block in enumerate(mesh.cells):
        if block.type not in to_type:
            raise ValueError(f"Gmsh MSH has no element type for meshio's {block.type!r}")
        dim = topo[block.type]
        phys = np.asarray(mesh.cell_data["gmsh:physical"][b]).reshape(-1).astype(np.int64)
        geo = np.asarray(mesh.cell_data["gmsh:geometrical"][b]).reshape(-1).astype(np.int64)
        for s, e in _runs(np.column_stack([geo, phys])):
            runs.append((b, s, e, dim, int(geo[s]), int(phys[s])))
    # a geometrical tag keeps its number when it stands for one physical tag in its dimension and is positive
    seen: dict = {}
    for _, _, _, dim, geo, phys in runs:
        seen.setdefault((dim, geo), set()).add(phys)
    used = {key for key, phys in seen.items() if key[1] > 0 and len(phys) == 1}
    fresh = {d: max([g for (dd, g) in seen if dd == d] + [0]) for d in range(4)}
    tag_of: dict = {}
    out, entities = [], {}
    for b, s, e, dim, geo, phys in runs:
        key = (dim, geo, phys)
        if key not in tag_of:
            if (dim, geo) in used:
                tag_of[key] = geo
            else:
                fresh[dim] += 1
                tag_of[key] = fresh[dim]
            entities[(dim, tag_of[key])] = phys
        out.append((b, s, e, dim, tag_of[key]))
    return out, entities


def _data_section(tag: str, name: str, values: np.ndarray) -> bytes:
    values = np.asarray(values, dtype=np.float64)
    values = values.reshape(len(values), -1)
    k = values.shape[1]
    head = f'${tag}\n1\n"{name}"\n1\n0.0\n3\n0\n{k}\n{len(values)}\n'.encode()
    rec = np.empty(len(values), dtype=[("index", "<i4"), ("v", "<f8", (k,))])
    rec["index"] = np.arange(1, len(values) + 1)
    rec["v"] = values
    return head + rec.tobytes() + f"\n$End{tag}\n".encode()


def write_msh41(path, mesh, node_dim_tags=None) -> None:
    """Write ``mesh`` (a prepared ``meshio.Mesh``) to ``path`` as binary MSH 4.1; ``node_dim_tags`` (N, 2): the
    entity (dim, tag) of every node (meshio's ``gmsh:dim_tags``), else every node goes on one entity."""
    to_type, to_order = _gmsh_tables()
    points = np.ascontiguousarray(np.asarray(mesh.points, dtype=np.float64))
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        raise ValueError(f"expected points of shape (N, 3), found {points.shape}")
    if points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    runs, entities = _entities(mesh)
    blocks = [np.asarray(to_order(b.type, np.asarray(b.data)), dtype=np.int64) for b in mesh.cells]
    parts = [b"$MeshFormat\n4.1 1 8\n", np.array([1], dtype="<i4").tobytes(), b"\n$EndMeshFormat\n"]
    if mesh.field_data:
        lines = [f"{len(mesh.field_data)}"]
        for name, value in mesh.field_data.items():
            tag, dim = (int(v) for v in np.asarray(value).ravel()[:2])
            lines.append(f'{dim} {tag} "{name}"')
        parts.append(("$PhysicalNames\n" + "\n".join(lines) + "\n$EndPhysicalNames\n").encode())

    # $Entities: bounding boxes of the elements' nodes, physical tag if any, no bounding entities
    boxes: dict = {}
    for b, s, e, dim, tag in runs:
        xyz = points[blocks[b][s:e].ravel()] if e > s else points[:0]
        lo, hi = (xyz.min(axis=0), xyz.max(axis=0)) if len(xyz) else (np.zeros(3), np.zeros(3))
        if (dim, tag) in boxes:
            lo, hi = np.minimum(lo, boxes[(dim, tag)][0]), np.maximum(hi, boxes[(dim, tag)][1])
        boxes[(dim, tag)] = (lo, hi)
    if not entities and len(points):  # nodes but no elements: one volume entity to hold them
        entities[(3, 1)] = 0
        boxes[(3, 1)] = (points.min(axis=0), points.max(axis=0))
    with_cells = set(entities)
    if node_dim_tags is not None:
        for s, e in _runs(node_dim_tags):
            key = (int(node_dim_tags[s, 0]), int(node_dim_tags[s, 1]))
            lo, hi = points[s:e].min(axis=0), points[s:e].max(axis=0)
            if key in boxes:
                lo, hi = np.minimum(lo, boxes[key][0]), np.maximum(hi, boxes[key][1])
            boxes[key] = (lo, hi)
            entities.setdefault(key, 0)
    counts = [sum(1 for (d, _) in entities if d == dim) for dim in range(4)]
    # meshio's MSH 4 reader gives gmsh:physical only for entities with a physical tag, and fails when some have
    # none: once any element has a physical tag, the others get physical tag 0 ("none", as in MSH 2.2)
    tagged = any(entities.values())
    ent = [b"$Entities\n", np.array(counts, dtype="<u8").tobytes()]
    for dim in range(4):
        for (d, tag), phys in sorted(entities.items()):
            if d != dim:
                continue
            lo, hi = boxes[(d, tag)]
            ent.append(np.array([tag], dtype="<i4").tobytes())
            ent.append(np.asarray(lo if d == 0 else np.concatenate([lo, hi]), dtype="<f8").tobytes())
            grouped = tagged and (d, tag) in with_cells
            ent.append(np.array([1 if grouped else 0], dtype="<u8").tobytes())
            if grouped:
                ent.append(np.array([phys], dtype="<i4").tobytes())
            if d > 0:
                ent.append(np.array([0], dtype="<u8").tobytes())
    ent.append(b"\n$EndEntities\n")
    parts += ent

    # $Nodes: tags 1..N in the mesh's order; on their gmsh:dim_tags entities if given, else on one entity
    n = len(points)
    host = max(entities, key=lambda dt: (dt[0], -dt[1])) if entities else (3, 1)
    node_runs = [(0, n, host)] if n else []
    if node_dim_tags is not None and n:
        node_runs = [(s, e, (int(node_dim_tags[s, 0]), int(node_dim_tags[s, 1])))
                     for s, e in _runs(node_dim_tags)]
    nodes = [b"$Nodes\n", np.array([len(node_runs), n, 1 if n else 0, n], dtype="<u8").tobytes()]
    for s, e, (dim, tag) in node_runs:
        nodes.append(np.array([dim, tag, 0], dtype="<i4").tobytes())
        nodes.append(np.array([e - s], dtype="<u8").tobytes())
        nodes.append(np.arange(s + 1, e + 1, dtype="<u8").tobytes())
        nodes.append(points[s:e].astype("<f8").tobytes())
    nodes.append(b"\n$EndNodes\n")
    parts += nodes

    # $Elements: one block per run, element tags 1..M in the mesh's order
    total = sum(e - s for _, s, e, _, _ in runs)
    els = [b"$Elements\n", np.array([len(runs), total, 1 if total else 0, total], dtype="<u8").tobytes()]
    next_tag = 1
    for b, s, e, dim, tag in runs:
        conn = blocks[b][s:e]
        els.append(np.array([dim, tag, to_type[mesh.cells[b].type]], dtype="<i4").tobytes())
        els.append(np.array([e - s], dtype="<u8").tobytes())
        rec = np.empty((e - s, 1 + conn.shape[1]), dtype="<u8")
        rec[:, 0] = np.arange(next_tag, next_tag + e - s)
        rec[:, 1:] = conn + 1
        els.append(rec.tobytes())
        next_tag += e - s
    els.append(b"\n$EndElements\n")
    parts += els

    for name, values in mesh.point_data.items():
        parts.append(_data_section("NodeData", name, values))
    for name, arrays in mesh.cell_data.items():
        if name in ("gmsh:physical", "gmsh:geometrical"):
            continue
        flat = np.concatenate([np.asarray(a).reshape(len(a), -1) for a in arrays]) if arrays else np.zeros((0, 1))
        parts.append(_data_section("ElementData", name, flat))
    with open(path, "wb") as f:
        f.write(b"".join(parts))
