"""TransitionDataset: round trip, resume after an interruption, corrupted files."""

import json
import zipfile

import numpy as np
import pytest

from pal import data as data_module
from pal.data import DatasetFileError, DatasetWriter, TransitionDataset, column_names
from pal.sim import BabblingEnv
from pal.sim import babbling as babbling_module
from pal.sim.babbling import BabbleConfig, babble, collect, replay

SMALL = BabbleConfig(body="finger", steps=250, seed=7, reset_every=100, chunk_size=60)


def assert_same_rows(a: TransitionDataset, b: TransitionDataset) -> None:
    assert len(a) == len(b) and a.column_names == b.column_names
    for name in a.column_names:
        np.testing.assert_array_equal(a.columns[name], b.columns[name], err_msg=name)
    for key in ("ctrl", "states", "step", "episode"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    root = tmp_path_factory.mktemp("ds") / "finger"
    return root, babble(SMALL, root)


def test_round_trip_matches_the_in_memory_run(written):
    root, ds = written
    assert sorted(p.name for p in root.iterdir()) == [
        "chunk_000000.npz",
        "chunk_000001.npz",
        "chunk_000002.npz",
        "chunk_000003.npz",
        "chunk_000004.npz",
        "metadata.json",
    ]
    loaded = TransitionDataset.load(root)
    assert_same_rows(loaded, ds)
    assert_same_rows(loaded, collect(SMALL))
    assert loaded.column_names == ["act.finger", "q_prev.finger", "dq.finger", "q.finger"]
    for name, col in loaded.columns.items():
        assert col.shape == (250, 1) and col.dtype == np.float32, name
    assert loaded.states.shape == (250, 4) and loaded.states.dtype == np.float64
    np.testing.assert_array_equal(loaded.step, np.arange(250))
    np.testing.assert_array_equal(loaded.episode, np.arange(250) // 100)


def test_metadata_records_provenance(written):
    root, ds = written
    meta = json.loads((root / "metadata.json").read_text())
    assert meta["body"] == "finger" and len(meta["mjcf_sha256"]) == 64
    assert meta["timestep"] == 0.005 and meta["frame_skip"] == 50 and meta["seed"] == 7
    assert meta["policy"]["name"] == "uniform" and meta["reset_every"] == 100
    assert {"python", "numpy", "mujoco", "gymnasium", "pal"} <= set(meta["versions"])
    assert meta["n_rows"] == 250 and meta["complete"] is True
    assert ds.metadata == meta


def test_columns_are_consistent_transitions(written):
    _, ds = written
    c = ds.columns
    # dq is computed in float64 before rounding
    np.testing.assert_allclose(c["q.finger"] - c["q_prev.finger"], c["dq.finger"], atol=1e-6)
    # q(t-1) of a step is q(t) of the step before, except across resets
    cont = ds.step[1:] % 100 != 0
    np.testing.assert_array_equal(c["q_prev.finger"][1:][cont], c["q.finger"][:-1][cont])
    np.testing.assert_array_equal(c["act.finger"][:, 0], ds.ctrl[:, 0])
    assert c["act.finger"].min() >= -1.0 and c["act.finger"].max() <= np.float32(0.33)


def test_stored_state_replays_the_stored_transition_exactly(written):
    _, ds = written
    env = BabblingEnv("finger")
    for i in (0, 1, 99, 100, 173, 249):
        q = replay(env, ds.state(i), ds.ctrl[i])
        assert np.float32(q[0]) == ds.columns["q.finger"][i, 0], i


def test_as_dict_and_split(written):
    _, ds = written
    cols = ds.as_dict()
    assert set(cols) == set(column_names(["finger"])) and cols["q.finger"].shape == (250, 1)
    cols["q.finger"][:] = 0  # a copy
    assert ds.columns["q.finger"].any()
    train, test = ds.split(0.8, seed=0)
    assert (len(train), len(test)) == (200, 50)
    assert sorted(np.concatenate([train.step, test.step]).tolist()) == list(range(250))
    np.testing.assert_array_equal(test.state(3), ds.state(int(test.step[3])))
    train2, _ = ds.split(0.8, seed=0)
    np.testing.assert_array_equal(train.step, train2.step)
    head = ds.subset(slice(0, 10))
    assert len(head) == 10 and head.states.shape == (10, 4)
    np.testing.assert_array_equal(head.columns["q.finger"], ds.columns["q.finger"][:10])
    with pytest.raises(ValueError, match="rows must be a slice"):
        ds.subset([0.5])
    with pytest.raises(ValueError, match="fraction must be in"):
        ds.split(1.0, seed=0)
    with pytest.raises(KeyError, match="unknown column"):
        ds.as_dict(["q.elbow"])
    with pytest.raises(IndexError):
        ds.state(250)


def test_resume_after_an_interrupted_write_gives_the_uninterrupted_data(written, tmp_path, monkeypatch):
    _, full = written
    root = tmp_path / "run"
    real_write = DatasetWriter.write_chunk
    calls = {"n": 0}

    def crashing_write(self, columns, rows, resume):
        calls["n"] += 1
        if calls["n"] == 3:  # crash in the middle of writing the third chunk
            path = self.root / "chunk_000002.npz"
            data_module.atomic_write(path, lambda fh: (fh.write(b"PK\x03\x04 partial"), _raise()))
        return real_write(self, columns, rows, resume)

    def _raise():
        raise KeyboardInterrupt("simulated interruption")

    monkeypatch.setattr(DatasetWriter, "write_chunk", crashing_write)
    with pytest.raises(KeyboardInterrupt):
        babble(SMALL, root)
    monkeypatch.undo()
    assert sorted(p.name for p in root.glob("chunk_*.npz")) == ["chunk_000000.npz", "chunk_000001.npz"]
    assert not list(root.glob(".*.tmp"))  # the temp file of the failed write was removed
    assert json.loads((root / "metadata.json").read_text()).get("n_rows") is None
    (root / ".chunk_000002.npz.leftover.tmp").write_bytes(b"junk")  # as after a hard kill

    with pytest.raises(ValueError, match="already holds a dataset; pass resume=True"):
        babble(SMALL, root)
    resumed = babble(SMALL, root, resume=True)
    assert_same_rows(resumed, full)
    assert not list(root.glob(".*.tmp"))
    # resuming a finished dataset is a no-op; a larger step count extends it
    assert_same_rows(babble(SMALL, root, resume=True), full)


def test_resume_with_the_ou_policy_and_extension(tmp_path):
    cfg = BabbleConfig(body="finger", steps=90, seed=1, policy="ou", reset_every=50, chunk_size=40)
    longer = BabbleConfig(**{**cfg.__dict__, "steps": 130})
    babble(cfg, tmp_path / "a")
    extended = babble(longer, tmp_path / "a", resume=True)
    assert_same_rows(extended, collect(longer))


def test_resume_refuses_a_different_configuration(written, tmp_path):
    root = tmp_path / "cfg"
    babble(BabbleConfig(steps=30, chunk_size=20), root)
    with pytest.raises(ValueError, match=r"configuration differs \(.*seed: stored 0 vs now 1"):
        babble(BabbleConfig(steps=30, chunk_size=20, seed=1), root, resume=True)


def _copy(root, tmp_path):
    import shutil

    dst = tmp_path / "copy"
    shutil.copytree(root, dst)
    return dst


def test_truncated_chunk_raises_naming_the_file(written, tmp_path):
    root = _copy(written[0], tmp_path)
    path = root / "chunk_000001.npz"
    path.write_bytes(path.read_bytes()[:500])
    with pytest.raises(DatasetFileError, match=r"chunk_000001\.npz is truncated or corrupted"):
        TransitionDataset.load(root)
    with pytest.raises(DatasetFileError, match=r"chunk_000001\.npz"):
        babble(SMALL, root, resume=True)


def test_corrupted_chunk_raises_naming_the_file(written, tmp_path):
    root = _copy(written[0], tmp_path)
    path = root / "chunk_000003.npz"
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["q.finger"][5] += 1.0  # a silent bit of damage, in a valid zip
    np.savez(path, **arrays)
    with pytest.raises(DatasetFileError, match=r"chunk_000003\.npz: checksum mismatch"):
        TransitionDataset.load(root)
    raw = bytearray((root / "chunk_000000.npz").read_bytes())
    raw[len(raw) // 2] ^= 0xFF  # a flipped byte inside the zip
    (root / "chunk_000000.npz").write_bytes(bytes(raw))
    with pytest.raises(DatasetFileError, match=r"chunk_000000\.npz"):
        TransitionDataset.load(root)


def test_missing_chunk_and_bad_metadata_raise(written, tmp_path):
    root = _copy(written[0], tmp_path)
    (root / "chunk_000002.npz").unlink()
    with pytest.raises(
        DatasetFileError, match=r"chunk_000003\.npz: chunk 3 starts at row 180, expected chunk 2"
    ):
        TransitionDataset.load(root)
    (root / "metadata.json").write_text('{"format": "pal.transitions/1", "body": ')
    with pytest.raises(DatasetFileError, match=r"metadata\.json is not readable JSON"):
        TransitionDataset.load(root)
    with pytest.raises(DatasetFileError, match=r"metadata\.json does not exist"):
        TransitionDataset.load(tmp_path / "nothing")
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "metadata.json").write_text(json.dumps({"format": "pal.transitions/1", "columns": []}))
    with pytest.raises(DatasetFileError, match="holds no complete chunk"):
        TransitionDataset.load(empty)


def test_chunks_are_plain_npz_without_pickle(written):
    root, _ = written
    with zipfile.ZipFile(root / "chunk_000000.npz") as zf:
        names = set(zf.namelist())
    assert {"act.finger.npy", "state.npy", "ctrl.npy", "__chunk__.npy"} <= names
    with np.load(root / "chunk_000000.npz", allow_pickle=False) as npz:
        assert all(npz[k].dtype != object for k in npz.files)


def test_pal_data_imports_neither_models_nor_inference_nor_mujoco():
    import ast
    import inspect

    tree = ast.parse(inspect.getsource(data_module))
    imported = {n.names[0].name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import)}
    imported |= {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert not imported & {"models", "inference", "mujoco"}
    tree = ast.parse(inspect.getsource(babbling_module))
    imported = {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert not imported & {"models", "inference"}
