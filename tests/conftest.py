import os
import sys

# the test helpers (oracle.py) live beside the tests
sys.path.insert(0, os.path.dirname(__file__))

import pytest  # noqa: E402

SHARED = os.path.normpath(os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data"))
BUNNY = os.path.join(SHARED, "bunny.vtk")


@pytest.fixture
def bunny_path():
    if not os.path.exists(BUNNY):
        pytest.skip(f"{BUNNY} is absent (the paper's bunny mesh is read in place, never copied)")
    return BUNNY
