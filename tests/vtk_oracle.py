"""The VTK-based dense-sampling oracle of the tests (see comparison.vtk_sampling: VTK's shape functions, no hexsos code)."""

from comparison.vtk_sampling import DOMAIN, ROUNDING, dense_min, det, grid, reference_nodes  # noqa: F401
