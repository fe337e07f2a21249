"""The build-time wing: code and data generated from the cells' exact tables before the package runs.

Owns: the generator of the kernel's straight-line code (:mod:`.codegen`, writes
``hexsos_plugins/kernel/generated.py``) and the ahead-of-time compilation of the kernel (:mod:`.extension`, run by
``setup.py``: the extension and ``kernel/tables.npz``). Nothing imports this wing at run time; it imports the kernel wing.
"""
