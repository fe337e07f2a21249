"""Ahead-of-time compilation of the kernel (numba's pycc), run by ``setup.py`` when the package is built.

The extension ``hexsos_plugins.kernel.aot`` holds the entry points of :mod:`hexsos_plugins.kernel.source`,
compiled from that same source with numba's default flags (no fastmath), with signatures derived from
:func:`hexsos_plugins.kernel.calls.entry_point_arguments`, and a fingerprint of the source:
:mod:`hexsos_plugins.kernel` uses the extension only when the fingerprint matches the source it ships with
(after an edit, until the package is built again, the source is compiled just in time instead).
Importing it needs numpy only: no numba at run time, no compilation on first use. The same build writes
``kernel/tables.npz``, every type's tables (:func:`hexsos_plugins.kernel.cell_tables.write_tables`), checked against a fingerprint
of their sources when loaded.
"""

from __future__ import annotations

import os

__all__ = ["extension"]


def extension():
    """A setuptools Extension that compiles the kernel (needs numba and numpy at build time)."""
    os.environ["HEXSOS_KERNEL"] = "jit"  # the kernel module must not look for the extension being built
    import numba
    import numba.pycc.compiler as pycc_compiler
    import numpy
    from numba.pycc import CC

    class _ReleaseGil(pycc_compiler.Flags):
        """pycc compiles its exports with default flags, which hold the GIL; the kernel's threads need it
        released during the compiled call, as numba's nogil=True does (the chunk functions touch no Python
        object)."""

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.release_gil = True

    pycc_compiler.Flags = _ReleaseGil

    from ..kernel import source
    from ..kernel.calls import entry_point_arguments
    from ..kernel.compiled import source_hash
    from ..kernel.cell_tables import write_tables

    cc = CC("aot", source_module="hexsos_plugins.kernel.source")
    for name, args in entry_point_arguments().items():
        sig = numba.void(*[numba.typeof(a) for a in args])
        cc.export(name, sig)(getattr(source, name).py_func)
    ns = {}
    exec(f"def source_hash_prefix():\n    return {int(source_hash()[:15], 16)}\n", ns)
    cc.export("source_hash_prefix", "i8()")(ns["source_hash_prefix"])
    write_tables()  # the tables too (exact rational arithmetic once, at build time)
    # numpy's headers first: numba puts the Python include directory first, where Debian's python3-numpy links
    # its own numpy headers (/usr/include/python3.X/numpy, NumPy 1.x), and an extension built against those fails
    # to import under the NumPy 2 the build environment (and the user's venv) holds
    return cc.distutils_extension(include_dirs=[numpy.get_include()])
