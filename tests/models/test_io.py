import json
import subprocess
import sys
import textwrap
import zipfile

import numpy as np
import pytest
import torch

from models import ModelFileError, WorldModel, finger_graph, load, save
from models.io import read_metadata


@pytest.fixture
def model():
    torch.manual_seed(3)
    m = WorldModel(finger_graph("state"))
    m.set_root_prior("q_prev.finger", -1.7, 0.8)
    return m


def inputs():
    g = torch.Generator().manual_seed(0)
    return {
        "act.finger": torch.rand(7, 1, generator=g) - 0.5,
        "q_prev.finger": torch.randn(7, 1, generator=g),
    }


def test_round_trip_gives_identical_predictions(model, tmp_path):
    path = save(model, tmp_path / "wm.npz", provenance={"seed": 3, "config": {"epochs": 1}})
    loaded = load(path, finger_graph("state"))
    with torch.no_grad():
        a, b = model.predict(inputs()), loaded.predict(inputs())
    for k in a:
        assert torch.equal(a[k], b[k])
    assert loaded.provenance["seed"] == 3
    assert "torch" in loaded.provenance["versions"]
    meta = read_metadata(path)
    assert meta["mechanisms"]["dq.finger"]["hidden"] == [32, 32]
    # no pickle: every entry loads with allow_pickle=False
    with np.load(path, allow_pickle=False) as npz:
        assert all(npz[k].dtype != object for k in npz.files)


def test_load_in_a_fresh_process(model, tmp_path):
    path = save(model, tmp_path / "wm.npz")
    with torch.no_grad():
        expected = model.predict(inputs())["q.finger"].numpy().ravel().tolist()
    script = textwrap.dedent(
        f"""
        import json, torch
        torch.set_num_threads(1)  # the same kernels as the test process
        from models import load, finger_graph
        g = torch.Generator().manual_seed(0)
        x = {{"act.finger": torch.rand(7, 1, generator=g) - 0.5, "q_prev.finger": torch.randn(7, 1, generator=g)}}
        m = load({str(path)!r}, finger_graph("state"))
        with torch.no_grad():
            print(json.dumps(m.predict(x)["q.finger"].numpy().ravel().tolist()))
        """
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert json.loads(out.stdout) == expected


def test_refuses_other_graph(model, tmp_path):
    path = save(model, tmp_path / "wm.npz")
    with pytest.raises(ModelFileError, match="does not match the expected"):
        load(path, finger_graph("thesis"))


def test_refuses_corrupted_and_truncated_files(model, tmp_path):
    path = save(model, tmp_path / "wm.npz")
    blob = path.read_bytes()
    (tmp_path / "trunc.npz").write_bytes(blob[: len(blob) // 2])
    with pytest.raises(ModelFileError, match="not a readable world-model file"):
        load(tmp_path / "trunc.npz")
    (tmp_path / "garbage.npz").write_bytes(b"not a zip at all")
    with pytest.raises(ModelFileError, match="not a readable"):
        load(tmp_path / "garbage.npz")
    with pytest.raises(ModelFileError, match="no world-model file"):
        load(tmp_path / "missing.npz")
    # a tensor altered on disk fails the checksum
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k].copy() for k in npz.files}
    key = next(k for k in arrays if k.startswith("state/") and arrays[k].size > 1)
    arrays[key][0] += 1.0
    np.savez(tmp_path / "tampered.npz", **arrays)
    with pytest.raises(ModelFileError, match="checksum mismatch"):
        load(tmp_path / "tampered.npz")
    # an npz that is not a model
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ModelFileError, match="no __meta__ entry"):
        load(tmp_path / "other.npz")
    assert zipfile.is_zipfile(path)


def test_save_is_atomic_and_leaves_no_temp_files(model, tmp_path):
    save(model, tmp_path / "wm.npz")
    save(model, tmp_path / "wm.npz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["wm.npz"]


def test_save_rejects_unserialisable_mechanisms_and_provenance(tmp_path):
    from models import FunctionMechanism, chain_graph

    m = WorldModel(chain_graph(), {"y": FunctionMechanism(torch.sin, 1)})
    with pytest.raises(ValueError, match="cannot be saved"):
        save(m, tmp_path / "x.npz")
    with pytest.raises(ValueError, match="not JSON-serialisable"):
        save(WorldModel(chain_graph()), tmp_path / "y.npz", provenance={"bad": object()})
    assert not (tmp_path / "y.npz").exists()
