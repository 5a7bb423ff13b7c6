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


WIRING = {"agent.py", "agent", "baselines", "cli.py", "experiments", "language"}


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


# ---------------------------------------------------------------------------- module import graph
PACKAGES = ("pal", "models", "inference")


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for package in PACKAGES for p in sources(package)}


def _resolve(name: str) -> str | None:
    """The known module ``name`` refers to (itself, or its longest known parent)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _type_checking_only(tree: ast.AST) -> set[int]:
    """ids of import nodes inside ``if TYPE_CHECKING:`` blocks (never executed)."""
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skip |= {id(n) for stmt in node.body for n in ast.walk(stmt)}
    return skip


def module_imports(
    name: str, source: str | None = None, is_package: bool | None = None, *, type_checking: bool = True
) -> set[str]:
    """Modules of pal/models/inference that module ``name`` imports anywhere: top level, in
    functions, absolute or relative, and in ``if TYPE_CHECKING:`` blocks unless ``type_checking``
    is false (a type-only import is still a dependency: the two modules cannot be read apart)."""
    path = MODULES.get(name)
    if source is None or is_package is None:
        assert path is not None, name
        source, is_package = path.read_text(), path.name == "__init__.py"
    tree = ast.parse(source)
    skip = set() if type_checking else _type_checking_only(tree)
    package = name if is_package else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")
                anchor = anchor[: len(anchor) - (node.level - 1)]
                base = ".".join([*anchor, *([node.module] if node.module else [])])
            targets = [
                f"{base}.{alias.name}" if f"{base}.{alias.name}" in MODULES else base for alias in node.names
            ]
        else:
            continue
        out |= {t for t in map(_resolve, targets) if t is not None and t != name}
    return out


GRAPH = {name: module_imports(name) for name in MODULES}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle as ``[a, b, ..., a]``, or None (iterative DFS with colours)."""
    state: dict[str, int] = {}
    for start in sorted(graph):
        if state.get(start):
            continue
        stack = [(start, iter(sorted(graph[start])))]
        path, state[start] = [start], 1
        while stack:
            node, children = stack[-1]
            child = next(children, None)
            if child is None:
                stack.pop()
                path.pop()
                state[node] = 2
            elif state.get(child) == 1:
                return [*path[path.index(child) :], child]
            elif not state.get(child):
                state[child] = 1
                path.append(child)
                stack.append((child, iter(sorted(graph.get(child, ())))))
    return None


def test_the_import_graph_sees_function_level_relative_and_type_only_imports():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None
    assert "pal.io.files" in GRAPH["pal.io.dataset"] | GRAPH["pal.io.dataset_files"]
    snippet = (
        "from typing import TYPE_CHECKING\n"
        "from . import tum\n"
        "from ..io import files\n"
        "from ..sim.env import BabblingEnv\n"
        "if TYPE_CHECKING:\n"
        "    import models.world\n"
        "def f():\n"
        "    import pal.frames\n"
        "    from pal.perception import frames\n"
    )
    runtime = {"pal.perception.tum", "pal.io.files", "pal.sim.env", "pal.frames", "pal.perception.frames"}
    assert module_imports("pal.perception.sequence", snippet, False, type_checking=False) == runtime
    assert module_imports("pal.perception.sequence", snippet, False) == runtime | {"models.world"}


def test_there_are_no_import_cycles():
    """Type-only imports (``if TYPE_CHECKING:``) count: a cycle through one is still a cycle."""
    cycle = find_cycle(GRAPH)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


@pytest.mark.parametrize("name", sorted(n for n in MODULES if n.startswith("pal.sim")))
def test_the_body_does_not_import_the_senses(name):
    senses = sorted(m for m in GRAPH[name] if m == "pal.perception" or m.startswith("pal.perception."))
    assert not senses, f"{name} imports {senses}; share code through pal.frames / pal.io.sequence_files"


@pytest.mark.parametrize(
    "path", sources("models") + sources("inference") + sources("pal"), ids=lambda p: str(p.relative_to(ROOT))
)
def test_only_the_ray_engine_imports_ray(path):
    if path.relative_to(ROOT).as_posix() == "pal/lab/ray_engine.py":
        return
    assert "ray" not in imports(path), f"{path} imports ray; Ray code lives in pal/lab/ray_engine.py"


# ---------------------------------------------------------------------------- size and documentation
MAX_MODULE_LINES = 500


@pytest.mark.parametrize(
    "path", sources("models") + sources("inference") + sources("pal"), ids=lambda p: str(p.relative_to(ROOT))
)
def test_modules_hold_one_concept(path):
    lines = len(path.read_text().splitlines())
    assert lines <= MAX_MODULE_LINES, f"{path.relative_to(ROOT)} has {lines} lines; split it by concept"


def package_directories() -> list[str]:
    """Every directory of models/inference/pal that holds Python modules, as a posix path."""
    found = {p.parent.relative_to(ROOT).as_posix() for pkg in PACKAGES for p in sources(pkg)}
    return sorted(found)


def test_architecture_md_names_every_package_directory():
    text = (ROOT / "ARCHITECTURE.md").read_text()
    missing = [d for d in package_directories() if f"{d}/" not in text and f"`{d}`" not in text]
    assert not missing, f"ARCHITECTURE.md does not name {missing}"


def test_the_architecture_check_sees_a_new_package():
    assert "pal/experiments/closed_loop" in package_directories()


MAX_FUNCTION_LINES = 80


def long_functions(source: str, limit: int = MAX_FUNCTION_LINES) -> list[tuple[str, int]]:
    """``(name, lines)`` of every function or method in ``source`` longer than ``limit`` lines."""
    out = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            lines = node.end_lineno - node.lineno + 1
            if lines > limit:
                out.append((node.name, lines))
    return out


def test_the_function_length_check_counts_from_def_to_the_last_line():
    body = "".join(f"    x{i} = {i}\n" for i in range(80))
    assert long_functions("def f():\n" + body) == [("f", 81)]
    assert long_functions("class A:\n    def g(self):\n        pass\n") == []


@pytest.mark.parametrize(
    "path", sources("models") + sources("inference") + sources("pal"), ids=lambda p: str(p.relative_to(ROOT))
)
def test_functions_fit_on_a_screen(path):
    found = long_functions(path.read_text())
    assert not found, f"{path.relative_to(ROOT)}: {found} over {MAX_FUNCTION_LINES} lines; split by their steps"
