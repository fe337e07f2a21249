"""Every docstring example of the library runs and prints what it says (doctest), module by module."""

import doctest
import importlib
import pkgutil
from pathlib import Path

import pytest

import hexsos_plugins

#: Modules not imported here: the compiled extension (a binary) and the build-time wing (it needs numba's compiler
#: and writes files); neither holds an example.
SKIP = ("hexsos_plugins.kernel.aot", "hexsos_plugins.generate.extension")


def library_modules():
    names = ["hexsos_plugins"]
    for info in pkgutil.walk_packages(hexsos_plugins.__path__, "hexsos_plugins."):
        if info.name not in SKIP and not info.name.endswith("__main__"):
            names.append(info.name)
    return names


def with_examples():
    out = []
    for name in library_modules():
        spec = importlib.util.find_spec(name)
        if spec.origin and spec.origin.endswith(".py") and ">>> " in Path(spec.origin).read_text():
            out.append(name)
    return out


def test_the_modules_with_examples_are_found():
    found = with_examples()
    assert {"hexsos_plugins.certify.pipeline", "hexsos_plugins.meshrepair.driver", "hexsos_plugins.io.mesh"} <= set(found)


@pytest.mark.parametrize("name", with_examples())
def test_docstring_examples_run(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, verbose=False, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0, f"{name} has '>>> ' in its source but doctest found no example"
    assert result.failed == 0


def test_a_wrong_example_fails():
    """The negative case: doctest reports an example whose output is not what it says."""
    def f():
        """
        >>> 1 + 1
        3
        """

    runner = doctest.DocTestRunner(verbose=False)
    for test in doctest.DocTestFinder().find(f, "f", globs={}):
        runner.run(test, out=lambda s: None)
    assert runner.failures == 1
