import atexit
import os
import shutil
import sys
import tempfile

# the test helpers (oracle.py) live beside the tests
sys.path.insert(0, os.path.dirname(__file__))

import pytest  # noqa: E402

# hexsos records the environments it runs in (for the ParaView plugin loaded by hand) under XDG_CONFIG_HOME:
# the suite records into a directory of its own, never into the user's home (subprocesses inherit it)
# (removed when the process ends: each pytest process, xdist's workers too, made one and left it behind)
os.environ["XDG_CONFIG_HOME"] = tempfile.mkdtemp(prefix="hexsos-tests-config-")
atexit.register(shutil.rmtree, os.environ["XDG_CONFIG_HOME"], True)

SHARED = os.path.normpath(os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data"))
BUNNY = os.path.join(SHARED, "bunny.vtk")


def published(name):
    """The path of a published mesh of ``../shared/data`` (``name`` relative to it), read in place and never copied;
    skips the calling test when it is absent."""
    path = os.path.join(SHARED, name)
    if not os.path.exists(path):
        pytest.skip(f"{path} is absent (published meshes are read in place, never copied)")
    return path


@pytest.fixture
def bunny_path():
    if not os.path.exists(BUNNY):
        pytest.skip(f"{BUNNY} is absent (the paper's bunny mesh is read in place, never copied)")
    return BUNNY


# the files that take longest start first, longest first (a wheel installed in a fresh venv with ParaView's GUI: 268 s
# of the suite's 989 s of work on 2026-12-03; the repair's optimizer: 166 s): with one worker per core (pyproject's
# addopts), a long file started last leaves the other core idle at the end (the suite: 10.8 min in xdist's own order of
# files, by test count, which ran the wheel's last; 8.8 min with it first)
LONGEST_FIRST = ("test_doors_wheel.py", "test_repair_optimize.py")


def pytest_collection_modifyitems(config, items):
    rank = {name: k for k, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(LONGEST_FIRST)))
