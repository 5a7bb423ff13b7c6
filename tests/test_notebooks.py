"""Execute the notebooks listed in ``notebooks/ci_notebooks.txt`` with ``CI=1`` set.

Notebooks are thin clients of the installed packages (DESIGN.md); this test runs each
listed one top to bottom in a fresh kernel, in a temporary working directory, and fails on
the first cell error.

The kernel is always ipykernel in the interpreter that runs pytest. The notebooks name the
kernelspec ``python3``, and a ``python3`` spec found first on the Jupyter path (for example
in ``~/.local/share/jupyter/kernels``) may point at another Python with other packages, so
the kernel manager below builds that spec from :func:`ipykernel.kernelspec.get_kernel_dict`,
whose ``argv[0]`` is ``sys.executable``.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import nbformat
import pytest
from ipykernel.kernelspec import RESOURCES, get_kernel_dict
from jupyter_client.kernelspec import KernelSpec, KernelSpecManager
from jupyter_client.manager import AsyncKernelManager
from nbclient import NotebookClient
from traitlets import default

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
CI_LIST = NOTEBOOKS / "ci_notebooks.txt"
KERNEL_NAME = "python3"
CELL_TIMEOUT = 300  # seconds per cell

pytestmark = pytest.mark.notebook


class ThisInterpreterSpecs(KernelSpecManager):
    """Resolves the kernel name ``python3`` to ipykernel in ``sys.executable``."""

    def get_kernel_spec(self, kernel_name: str) -> KernelSpec:
        if kernel_name == KERNEL_NAME:
            return KernelSpec(resource_dir=RESOURCES, **get_kernel_dict())
        return super().get_kernel_spec(kernel_name)


class ThisInterpreterKernelManager(AsyncKernelManager):
    """nbclient's default kernel manager, with :class:`ThisInterpreterSpecs`."""

    @default("kernel_spec_manager")
    def _kernel_spec_manager_default(self) -> KernelSpecManager:
        return ThisInterpreterSpecs(data_dir=self.data_dir)


def listed_notebooks() -> list[str]:
    """Entries of ci_notebooks.txt: non-blank lines that do not start with '#'."""
    if not CI_LIST.is_file():
        return []
    lines = (line.strip() for line in CI_LIST.read_text(encoding="utf-8").splitlines())
    return [line for line in lines if line and not line.startswith("#")]


def kernel_env() -> dict[str, str]:
    """The test process's environment with CI=1 and without a forced matplotlib backend."""
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}  # tests/conftest.py sets Agg
    env["CI"] = "1"
    return env


def execute(nb: nbformat.NotebookNode, cwd: Path) -> nbformat.NotebookNode:
    """Run every cell of ``nb`` in a fresh kernel with cwd ``cwd``; raises on a cell error."""
    client = NotebookClient(
        nb,
        timeout=CELL_TIMEOUT,
        kernel_name=KERNEL_NAME,
        kernel_manager_class=ThisInterpreterKernelManager,
        allow_errors=False,
        resources={"metadata": {"path": str(cwd)}},
    )
    return client.execute(env=kernel_env())


def test_ci_list_names_existing_notebooks() -> None:
    names = listed_notebooks()
    assert CI_LIST.is_file(), f"{CI_LIST} is missing; list one notebook path per line"
    assert names, f"{CI_LIST} lists no notebook; add one path per line (relative to notebooks/)"
    missing = [n for n in names if not (NOTEBOOKS / n).is_file()]
    assert not missing, f"{CI_LIST} names notebooks that do not exist: {missing}"
    duplicates = sorted({n for n in names if names.count(n) > 1})
    assert not duplicates, f"{CI_LIST} lists {duplicates} more than once"


@pytest.mark.slow
def test_kernel_runs_this_interpreter(tmp_path: Path) -> None:
    """The kernel is this venv's Python, sees CI=1, and imports the installed packages."""
    probe = (
        "import json, os, sys\n"
        "import inference, models\n"
        "print(json.dumps({'prefix': sys.prefix, 'ci': os.environ.get('CI'), 'cwd': os.getcwd(),\n"
        "                  'inference': inference.__file__, 'models': models.__file__}))"
    )
    nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(probe)])
    out = execute(nb, tmp_path)
    stdout = "".join(o["text"] for o in out.cells[0].outputs if o.get("name") == "stdout")
    facts = json.loads(stdout)
    assert facts["prefix"] == sys.prefix, f"kernel runs in {facts['prefix']}, expected {sys.prefix}"
    assert facts["ci"] == "1"
    assert Path(facts["cwd"]).resolve() == tmp_path.resolve()
    for pkg in ("inference", "models"):
        assert facts[pkg] is not None, (
            f"in the kernel {pkg!r} imports as a namespace package (no __init__.py found); the "
            "editable install is stale: run `pip install -e .` again"
        )


@pytest.mark.slow
@pytest.mark.parametrize("name", listed_notebooks())
def test_notebook_runs(name: str, tmp_path: Path) -> None:
    path = NOTEBOOKS / name
    assert path.is_file(), f"{CI_LIST} names {name!r}, but {path} does not exist"
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    execute(nb, tmp_path)
