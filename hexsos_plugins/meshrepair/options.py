"""The repair's options and the one rule for their defaults, used by the library and by every door (the CLI,
the Gmsh panel, the ParaView filter).

Imports :mod:`hexsos_plugins.errors` only.
"""

from __future__ import annotations

from ..errors import InvalidInputError

__all__ = ["METHODS", "BOUNDARY_MODES", "DEFAULT_MARGIN", "DEFAULT_RHO", "SURFACE_TOLERANCE", "default_boundary",
           "resolve_boundary", "door_boundary"]

#: The repair methods: the optimizer (default) and the paper's Algorithms 1 and 2.
METHODS = ("optimize", "paper")
#: What boundary vertices may do: slide on the input's surface, stay fixed, or move freely.
BOUNDARY_MODES = ("slide", "fixed", "free")
#: Default relative margin: (R) asks det J(u*) >= DEFAULT_MARGIN * h^3 (h: the hex's mean edge length).
DEFAULT_MARGIN = 1e-3
#: The paper's balancing parameter of Algorithm 2.
DEFAULT_RHO = 200.0
#: ``boundary="slide"``: how far (a fraction of its mean boundary edge length) a boundary vertex may end off the
#: input surface, its feature curve or its feature corner. On a curved surface a quad cannot be square, so the
#: surface caps the minimum: the worst hexes of published meshes have 5-7 vertices on it. Measured on the eight
#: published meshes of ../shared/data (README): exactly on the surface the minimum was 0.28-0.52 on seven of them;
#: with 0.1, 0.52-0.69; with 0.2, 0.61-0.86 (kitten_with_bifur_3, whose worst hexes are inside, 0.27), every
#: boundary vertex within 1.9% of the diagonal of the input surface (the published optimizers leave theirs within
#: 0.15-1.4%, ../shared/GUIDE.md); with 0.35 (at most 1.2% of the diagonal:
#: :data:`hexsos_plugins.meshrepair.boundary.BAND_DIAGONAL`) 0.72-0.93, the boundary within 0.33-1.87% of the
#: diagonal but the bunny's 3.3% (its input's fold); with 0.5 two more beyond 2%
SURFACE_TOLERANCE = 0.35


def default_boundary(method: str = "optimize", pin_boundary: bool = False) -> str:
    """The boundary mode used when none is given: ``"fixed"`` with ``pin_boundary``, else ``"slide"`` for the
    optimizer and ``"free"`` for the paper's method (which knows no sliding).

    >>> default_boundary(), default_boundary("paper"), default_boundary("optimize", pin_boundary=True)
    ('slide', 'free', 'fixed')
    """
    if pin_boundary:
        return "fixed"
    return "free" if method == "paper" else "slide"


def resolve_boundary(boundary, method: str = "optimize", pin_boundary: bool = False) -> str:
    """``boundary`` checked against :data:`BOUNDARY_MODES`, or the default of :func:`default_boundary` when it is
    None (``pin_boundary`` wins over an explicit mode, as ``--pin-boundary`` always has)."""
    if boundary is None or pin_boundary:
        return default_boundary(method, pin_boundary)
    if boundary not in BOUNDARY_MODES:
        raise InvalidInputError(f"boundary: expected one of {', '.join(BOUNDARY_MODES)}, found {boundary!r}")
    return boundary


def door_boundary(boundary, method: str = "optimize", pin_boundary: bool = False) -> str:
    """The boundary mode of a door whose form always holds a choice (the Gmsh panel, the ParaView filter, whose
    default is ``"slide"``): as :func:`resolve_boundary`, except that the paper's method, which knows no sliding,
    turns ``"slide"`` into ``"free"`` instead of refusing it.

    >>> door_boundary("slide", "paper"), door_boundary("slide", "optimize"), door_boundary("free", "paper", True)
    ('free', 'slide', 'fixed')
    """
    mode = resolve_boundary(boundary, method, pin_boundary)
    return "free" if method == "paper" and mode == "slide" else mode
