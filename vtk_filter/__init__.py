"""VTK filters of hexsos (``VTKPythonAlgorithmBase``) and the ParaView plugin.

``HexSOSCheckFilter`` and ``HexSOSRepairFilter`` live in :mod:`vtk_filter.hexsos_paraview_plugin`, one file
that is both the filters for plain VTK and the ParaView plugin. The names below are resolved lazily: ParaView
loads *every* ``.py`` file of a ``PV_PLUGIN_PATH`` directory as a plugin, this one included (as a module
named ``__init__``), so this file must run nothing and register nothing.
"""

__all__ = ["HexSOSCheckFilter", "HexSOSRepairFilter", "HexSOSSafeStepFilter", "STATUS_NOT_A_HEX", "dependency_paths"]


def __getattr__(name):
    if name in __all__:
        from vtk_filter import hexsos_paraview_plugin

        return getattr(hexsos_paraview_plugin, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + __all__)
