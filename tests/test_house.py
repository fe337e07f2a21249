"""The house's rules, read from the code itself: every import of hexsos_plugins goes to its own wing or one below
(no arrow up), no import circle between wings, and no private name (``_x``) of a module used by another."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("hexsos_plugins", "gmsh_plugin", "vtk_filter", "comparison")
#: The wings from the bottom up; a module may import its own wing and the wings before it.
WINGS = ("errors", "cells", "kernel", "certify", "io", "meshrepair", "examples", "viz", "generate", "doors", "cli",
         "comparison")


def wing(module: str) -> str:
    parts = module.split(".")
    if parts[0] in ("gmsh_plugin", "vtk_filter"):
        return "doors"
    if parts[0] == "comparison":
        return "comparison"
    if len(parts) == 1 or parts[1] in ("__init__", "__main__"):
        return "top"  # the package's face: re-exports on first use, imports everything
    return {"_version": "errors"}.get(parts[1], parts[1])


def modules():
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).with_suffix("")
            name = ".".join(rel.parts)
            yield (name[: -len(".__init__")] if name.endswith(".__init__") else name), path


def imports(name, path):
    """(imported module, imported name or None) for every import in the file, lazy ones included."""
    is_pkg = path.name == "__init__.py"
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                src = ".".join(base + ([node.module] if node.module else []))
            else:
                src = node.module or ""
            if src.split(".")[0] in PACKAGES:
                for a in node.names:
                    yield src, a.name
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] in PACKAGES:
                    yield a.name, None


def is_module(dotted):
    p = ROOT.joinpath(*dotted.split("."))
    return p.with_suffix(".py").exists() or (p / "__init__.py").exists()


def arrows():
    for name, path in modules():
        for src, item in imports(name, path):
            target = f"{src}.{item}" if item and is_module(f"{src}.{item}") else src
            yield name, target, item


def test_no_private_name_is_used_outside_its_module():
    found = sorted({f"{name} imports {src}.{item}" for name, src, item in arrows()
                    if item and item.startswith("_") and not item.startswith("__")})
    assert found == []


def test_imports_go_down_the_wings_only():
    up = []
    for name, target, _ in arrows():
        a, b = wing(name), wing(target)
        if a == "top" or b == "top" and target == "hexsos_plugins" and a in ("doors", "comparison"):
            continue
        if b == "top" or a not in WINGS or b not in WINGS:
            up.append(f"{name} -> {target} (wings {a} -> {b})")
        elif WINGS.index(b) > WINGS.index(a):
            up.append(f"{name} -> {target} ({a} above {b}? no: {b} is above {a})")
    assert up == []


def test_the_checks_would_see_an_arrow_up_and_a_private_import(tmp_path):
    """The negative case: the rules above recognise a violation when one is written."""
    src = "from ..cli import main\nfrom .tables import _TABLES\n"
    path = tmp_path / "calls.py"
    path.write_text(src)
    found = list(imports("hexsos_plugins.kernel.calls", path))
    assert ("hexsos_plugins.cli", "main") in found and ("hexsos_plugins.kernel.tables", "_TABLES") in found
    assert WINGS.index(wing("hexsos_plugins.cli")) > WINGS.index(wing("hexsos_plugins.kernel.calls"))


@pytest.mark.parametrize("pkg", ["hexsos_plugins"])
def test_every_wing_says_what_it_owns_and_may_import(pkg):
    for init in sorted((ROOT / pkg).glob("*/__init__.py")):
        if init.parent.name == "readers":
            continue
        doc = ast.get_docstring(ast.parse(init.read_text())) or ""
        assert "Owns" in doc and ("import" in doc), f"{init.parent.name}: the wing's docstring must say what it owns and imports"
