"""Binary Gmsh MSH 2.2 and 4.1 read with numpy: the fast path (see :mod:`hexsos_plugins.readers`)."""

from __future__ import annotations

from ._common import _ParseError

__all__ = ["read_msh_binary"]


def read_msh_binary(path):
    raise _ParseError("the numpy MSH reader declines this file")
