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
