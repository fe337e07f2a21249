import os
import sys
import tempfile

# the test helpers (oracle.py) live beside the tests
sys.path.insert(0, os.path.dirname(__file__))

import pytest  # noqa: E402

# hexsos records the environments it runs in (for the ParaView plugin loaded by hand) under XDG_CONFIG_HOME:
# the suite records into a directory of its own, never into the user's home (subprocesses inherit it)
os.environ["XDG_CONFIG_HOME"] = tempfile.mkdtemp(prefix="hexsos-tests-config-")

SHARED = os.path.normpath(os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data"))
BUNNY = os.path.join(SHARED, "bunny.vtk")


@pytest.fixture
def bunny_path():
    if not os.path.exists(BUNNY):
        pytest.skip(f"{BUNNY} is absent (the paper's bunny mesh is read in place, never copied)")
    return BUNNY


# the files that take longest (a wheel installed in a fresh venv, ParaView's GUI) start first: with one worker per
# core (pyproject's addopts), a long file started last would leave the other core idle at the end
LONGEST_FIRST = ("test_doors_wheel.py",)


def pytest_collection_modifyitems(config, items):
    items.sort(key=lambda item: item.path.name not in LONGEST_FIRST)
