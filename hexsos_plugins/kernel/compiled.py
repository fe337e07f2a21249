"""Loading the compiled kernel: the extension built at install (:mod:`hexsos_plugins.kernel.aot`) when it was
built from this very source, else numba's just-in-time compilation of :mod:`hexsos_plugins.kernel.source` (cached).

Owns: which implementation runs (:data:`impl`), the source's fingerprint. Imports nothing of hexsos but its own
compiled source.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

__all__ = ["impl", "KIND", "implementation", "source_hash", "compiles_at_first_use", "jit_cached", "load"]

SOURCES = ("source.py", "generated.py")  # what the extension is compiled from, in this folder


def source_hash() -> str:
    """SHA-256 of the kernel's source (:mod:`hexsos_plugins.kernel.source` and the products generated from the
    tables, :mod:`hexsos_plugins.kernel.generated`): the compiled extension records it."""
    h = hashlib.sha256()
    for name in SOURCES:
        h.update(Path(__file__).with_name(name).read_bytes())
    return h.hexdigest()


def load():
    """The compiled extension if it exists and was built from this source (``HEXSOS_KERNEL=jit`` forces the
    just-in-time path, ``=aot`` requires the extension); else numba's just-in-time compilation of the source."""
    want = os.environ.get("HEXSOS_KERNEL", "").lower()
    if want != "jit":
        try:
            from . import aot

            if aot.source_hash_prefix() == int(source_hash()[:15], 16):
                return aot, "aot"
            if want == "aot":
                raise ImportError("hexsos_plugins.kernel.aot was built from another source")
        except ImportError:
            if want == "aot":
                raise
    from . import source as jit

    return jit, "jit"


impl, KIND = load()


def implementation() -> str:
    """``"aot"`` (the extension compiled at install) or ``"jit"`` (numba, compiled at first use, cached)."""
    return KIND


def jit_cached(dispatcher):
    """Whether numba's cache holds machine code of this ``cache=True`` function for its current source (None:
    numba's cache cannot be read)."""
    try:
        return bool(dispatcher._cache._cache_file._load_index())
    except Exception:  # numba's cache internals: unknown, not an error
        return None


def compiles_at_first_use() -> bool:
    """Whether the kernel runs just in time with nothing cached for this source yet: its first call compiles it
    (one to two minutes, once)."""
    return KIND == "jit" and jit_cached(impl.run_chunk) is False

