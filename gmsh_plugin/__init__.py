"""The Gmsh door of hexsos: check every 3-D element of a Gmsh model and repair it, in scripts or in the Gmsh GUI.

* Scripts: :func:`check_model`, :func:`repair_model`, :func:`safe_step_model`, :func:`post_views` work on the current Gmsh model
  (``gmsh.initialize()`` first); see :mod:`gmsh_plugin.model`.
* GUI: ``hexsos-gmsh MESH`` (or ``python -m gmsh_plugin MESH``) opens Gmsh with the ONELAB panel "hexsos";
  see :mod:`gmsh_plugin.panel` and :mod:`gmsh_plugin.__main__`.

Importing this package does not import ``gmsh``: that happens on the first call.
"""

from gmsh_plugin.model import (
    HEX8,
    VIEW_ARGMIN,
    VIEW_DISPLACEMENT,
    VIEW_MIN_DET,
    VIEW_NAMES,
    VIEW_SAFE_STEP,
    VIEW_STATUS,
    GmshCells,
    GmshHexes,
    GmshModelError,
    add_hex_mesh,
    check_model,
    hexsos_views,
    model_cells,
    model_hexes,
    post_displacement,
    post_views,
    remove_views,
    repair_model,
    safe_step_model,
    world_points,
    write_views,
)
from gmsh_plugin.panel import ACTION_CHECK, ACTION_REPAIR, define_parameters, event_loop, handle_action

__all__ = [
    "check_model",
    "repair_model",
    "safe_step_model",
    "VIEW_SAFE_STEP",
    "post_views",
    "post_displacement",
    "model_cells",
    "model_hexes",
    "add_hex_mesh",
    "hexsos_views",
    "remove_views",
    "write_views",
    "world_points",
    "GmshCells",
    "GmshHexes",
    "GmshModelError",
    "HEX8",
    "VIEW_MIN_DET",
    "VIEW_STATUS",
    "VIEW_ARGMIN",
    "VIEW_DISPLACEMENT",
    "VIEW_NAMES",
    "ACTION_CHECK",
    "ACTION_REPAIR",
    "define_parameters",
    "handle_action",
    "event_loop",
]
