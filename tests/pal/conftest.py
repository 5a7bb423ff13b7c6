"""Fixtures shared by the tests of pal's packages."""

from __future__ import annotations

import warnings
from collections.abc import Callable

import pyro
import pytest
import torch

from inference import PoorPosteriorWarning
from pal.lab import registry
from pal.lab.runner import RunRecord, execute

TinyRun = Callable[[str, str], RunRecord]


@pytest.fixture(scope="session")
def tiny_run() -> TinyRun:
    """``tiny_run(kind, name)``: the entry's run on its tiny config, made once per session on first use.

    The registry's contract test and the experiment tests read the same record, so each
    registered entry's tiny run costs its time once. Each run starts from the seeds a test
    starts from (tests/conftest.py), whichever test asks first. Tests read the record and
    must not change it.
    """
    records: dict[tuple[str, str], RunRecord] = {}

    def run(kind: str, name: str) -> RunRecord:
        if (kind, name) not in records:
            entry = registry.get(kind, name)
            pyro.set_rng_seed(0)
            pyro.clear_param_store()
            torch.set_num_threads(1)
            with warnings.catch_warnings():
                # tiny configs give the agents' state estimates a few SVI steps on purpose
                warnings.simplefilter("ignore", PoorPosteriorWarning)
                records[kind, name] = execute(entry, entry.tiny)
            pyro.clear_param_store()
        return records[kind, name]

    return run
