"""Lets Debian's ParaView 5.11 load Python plugins on Python >= 3.11.

ParaView 5.11's plugin loader (``paraview.detail.pythonalgorithm``) imports ``inspect.getargspec``, which
Python 3.11 removed, so every Python plugin fails to load ("Problem loading plugin") before any of the plugin's
own code runs. Python imports ``usercustomize`` at start-up from ``sys.path``: put this directory on
``PYTHONPATH`` when starting ``paraview``/``pvpython``/``pvbatch`` (the hexsos plugin's ``python -m
vtk_filter.hexsos_paraview_plugin`` prints the line). Harmless elsewhere: it only adds the old name.
"""

import inspect

if not hasattr(inspect, "getargspec"):
    inspect.getargspec = inspect.getfullargspec
