"""The dependency rules of DESIGN.md, checked on the source's import statements."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
STDLIB = set(sys.stdlib_module_names) | {"__future__"}


def imports(path: Path) -> set[str]:
    """Top-level names of every module imported anywhere in ``path``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def full_imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
    return names


def sources(package: str) -> list[Path]:
    return sorted((ROOT / package).rglob("*.py"))


def test_packages_exist():
    for package in ("models", "inference", "pal"):
        assert sources(package), package


@pytest.mark.parametrize("path", sources("models"), ids=lambda p: str(p.relative_to(ROOT)))
def test_models_depend_on_torch_pyro_networkx_only(path):
    third_party = imports(path) - STDLIB - {"models"}
    # numpy backs the .npz format; matplotlib is imported lazily by plot helpers only
    assert third_party <= {"torch", "pyro", "networkx", "numpy", "matplotlib"}, third_party


@pytest.mark.parametrize("path", sources("inference"), ids=lambda p: str(p.relative_to(ROOT)))
def test_inference_never_imports_pal_mujoco_or_opencv(path):
    found = imports(path)
    assert not found & {"pal", "mujoco", "cv2", "gymnasium"}, found


@pytest.mark.parametrize(
    "path",
    [p for p in sources("pal") if p.parts[len(ROOT.parts) + 1] in ("sim", "perception")],
    ids=lambda p: str(p.relative_to(ROOT)),
)
def test_body_and_senses_do_not_import_the_world_model(path):
    assert not imports(path) & {"models", "inference"}


WIRING = {"agent.py", "agent", "cli.py", "experiments"}


@pytest.mark.parametrize("path", sources("pal"), ids=lambda p: str(p.relative_to(ROOT)))
def test_only_the_composition_root_wires_the_parts(path):
    top = path.relative_to(ROOT / "pal").parts[0]
    if top in WIRING:
        return
    assert not imports(path) & {"models", "inference"}, f"{path} imports models/inference"


@pytest.mark.parametrize(
    "path", sources("models") + sources("inference") + sources("pal"), ids=lambda p: str(p.relative_to(ROOT))
)
def test_no_print_or_show_in_library_code(path):
    if path.name in ("cli.py", "__main__.py"):
        return
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            func = node.func
            name = (
                func.id
                if isinstance(func, ast.Name)
                else func.attr
                if isinstance(func, ast.Attribute)
                else ""
            )
            assert name not in ("print", "show"), f"{path}:{node.lineno} calls {name}()"
