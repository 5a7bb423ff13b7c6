"""Every test starts from fixed seeds and an empty Pyro parameter store."""

from __future__ import annotations

import os

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("MUJOCO_GL", "egl")
# Tests use tiny arrays: BLAS/OpenMP thread pools only add contention on a busy 2-core box.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np
import pyro
import pytest
import torch

# Module- and session-scoped fixtures run before the first test's seeding below: one thread from the start.
torch.set_num_threads(1)


@pytest.fixture(scope="session", autouse=True)
def _private_cache(tmp_path_factory):
    """Experiments cache babbling data; tests keep theirs out of the user's cache directory."""
    previous = os.environ.get("PAL_CACHE_DIR")
    os.environ["PAL_CACHE_DIR"] = str(tmp_path_factory.mktemp("pal-cache"))
    yield
    if previous is None:
        os.environ.pop("PAL_CACHE_DIR", None)
    else:
        os.environ["PAL_CACHE_DIR"] = previous


@pytest.fixture(autouse=True)
def _seed_everything():
    pyro.set_rng_seed(0)
    pyro.clear_param_store()
    torch.set_num_threads(1)  # small tensors: one thread is faster and immune to a busy second core
    yield
    torch.set_num_threads(1)  # a test that changed it (the CLI's --threads) does not slow the next fixture
    import matplotlib.pyplot as plt

    plt.close("all")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)
