"""The certify wing: ``check(points, cells)``, the validity pipeline from arrays to proven verdicts.

Owns: the pipeline (:mod:`.pipeline`: input validation, the kernel on every cell, SOS where a hexahedron's
bracket stays open, exact decisions, :class:`CheckResult`) and its spread over processes or a Dask cluster
(:mod:`.parallel`); along a displacement, the certified largest safe step (:mod:`.safe_step`: t* with
every cell proven valid on [0, t*], a witness just past it).

May import: the kernel and cells wings, :mod:`hexsos_plugins.errors`. Never files, doors or the repair.
"""

from .pipeline import (HEX_TYPES, METHOD_NAMES, SOS_STATUS_NAMES, STATUS_NAMES, CheckResult, check, validate_arrays,
                       validate_cells)

__all__ = ["check", "CheckResult", "METHOD_NAMES", "STATUS_NAMES", "SOS_STATUS_NAMES", "validate_arrays",
           "validate_cells", "HEX_TYPES"]
