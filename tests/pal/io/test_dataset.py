"""TransitionDataset: round trip, resume after an interruption, corrupted files."""

import json
import multiprocessing
import os
import shutil
import socket
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from pal.io import dataset as data_module
from pal.io.dataset import (
    DatasetFileError,
    DatasetWriter,
    DirectoryLockedError,
    TransitionDataset,
    column_names,
    read_chunk,
)
from pal.io.dataset_files import metadata_checksum
from pal.io.files import atomic_write, read_npz, write_npz
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
    names = [
        "act.finger",
        "q_prev.finger",
        "dq_prev.finger",
        "dq.finger",
        "q.finger",
        "v_prev.finger",
        "v.finger",
    ]
    assert loaded.column_names == names
    assert loaded.column_names == column_names(["finger"], velocities=True)
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
    assert meta["format"] == "pal.transitions/4" and meta["action_ranges"] == {"finger": [-1.0, 0.33]}
    assert meta["actuator_force_limits"] == {"finger": None} and meta["effective_range_probe"] is None
    found = meta["effective_ranges"]["finger"]
    assert found["joint"] == "finger" and found["babbled"] == [-1.0, 0.33]
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
    # dq_prev(t) is dq(t-1) within an episode (across chunk files too), 0 at an episode's first step
    np.testing.assert_array_equal(c["dq_prev.finger"][1:][cont], c["dq.finger"][:-1][cont])
    starts = ds.step % 100 == 0
    assert (c["dq_prev.finger"][starts] == 0).all() and (c["dq_prev.finger"][~starts] != 0).all()
    assert c["act.finger"].min() >= -1.0 and c["act.finger"].max() <= np.float32(0.33)


def test_stored_state_replays_the_stored_transition_exactly(written):
    _, ds = written
    env = BabblingEnv("finger")
    for i in (0, 1, 99, 100, 173, 249):
        q = replay(env, ds.state(i), ds.ctrl[i])
        assert np.float32(q[0]) == ds.columns["q.finger"][i, 0], i


def test_to_dict_and_split(written):
    _, ds = written
    cols = ds.to_dict()
    assert set(cols) == set(column_names(["finger"], velocities=True)) and cols["q.finger"].shape == (250, 1)
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
        ds.to_dict(["q.elbow"])
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
            atomic_write(path, lambda fh: (fh.write(b"PK\x03\x04 partial"), _raise()))
        return real_write(self, columns, rows, resume)

    def _raise():
        raise KeyboardInterrupt("simulated interruption")

    monkeypatch.setattr(DatasetWriter, "write_chunk", crashing_write)
    with pytest.raises(KeyboardInterrupt):
        babble(SMALL, root)
    monkeypatch.undo()
    assert sorted(p.name for p in root.glob("chunk_*.npz")) == ["chunk_000000.npz", "chunk_000001.npz"]
    assert not list(root.glob(".*.tmp"))  # the temp file of the failed write was removed
    assert not (root / "writer.lock").exists()  # the interruption released the lock
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
    dst = tmp_path / "copy"
    shutil.copytree(root, dst)
    return dst


def test_truncated_chunk_raises_naming_the_file(written, tmp_path):
    root = _copy(written[0], tmp_path)
    path = root / "chunk_000001.npz"
    path.write_bytes(path.read_bytes()[:500])
    with pytest.raises(DatasetFileError, match=r"chunk_000001\.npz is not a readable"):
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
    with pytest.raises(DatasetFileError, match=r"chunk_000002\.npz is missing: the manifest lists it"):
        TransitionDataset.load(root)
    (root / "metadata.json").write_text('{"format": "pal.transitions/1", "body": ')
    with pytest.raises(DatasetFileError, match=r"metadata\.json is not readable JSON"):
        TransitionDataset.load(root)
    with pytest.raises(DatasetFileError, match=r"metadata\.json does not exist"):
        TransitionDataset.load(tmp_path / "nothing")
    empty = tmp_path / "empty"
    empty.mkdir()
    meta = {"format": data_module.FORMAT, "columns": [], "run_id": "r", "chunks": [], "complete": True}
    (empty / "metadata.json").write_text(json.dumps({**meta, "metadata_checksum": metadata_checksum(meta)}))
    with pytest.raises(DatasetFileError, match="holds no complete chunk"):
        TransitionDataset.load(empty)
    (empty / "metadata.json").write_text(json.dumps({**meta, "format": "pal.transitions/1"}))
    with pytest.raises(DatasetFileError, match=r"older layout without a chunk manifest; babble"):
        TransitionDataset.load(empty)
    (empty / "metadata.json").write_text(json.dumps({**meta, "format": "pal.transitions/2"}))
    with pytest.raises(DatasetFileError, match=r"older layout without the dq_prev columns; babble"):
        TransitionDataset.load(empty)


def test_chunks_are_plain_npz_without_pickle(written):
    root, _ = written
    with zipfile.ZipFile(root / "chunk_000000.npz") as zf:
        names = set(zf.namelist())
    assert {"act.finger.npy", "state.npy", "ctrl.npy", "__meta__.npy"} <= names
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


# ---------------------------------------------------------------------------- single writer
TINY_META = {"columns": ["q.j"], "seed": 0}


def _tiny_chunk(writer, n=3, value=0.0):
    cols = {"q.j": np.full((n, 1), value, np.float32)}
    rows = {
        "ctrl": np.zeros((n, 1), np.float32),
        "state": np.zeros((n, 2)),
        "step": np.arange(writer.rows, writer.rows + n),
        "episode": np.zeros(n, np.int64),
    }
    return writer.write_chunk(cols, rows, {"step": writer.rows + n})


def test_a_second_writer_is_refused_naming_the_directory_and_the_holder(tmp_path):
    root = tmp_path / "ds"
    with DatasetWriter(root, TINY_META) as first:
        holder = json.loads((root / "writer.lock").read_text())
        assert holder["pid"] == os.getpid() and holder["host"] == socket.gethostname()
        with pytest.raises(DirectoryLockedError, match=rf"{root} is being written by pid {os.getpid()}"):
            DatasetWriter(root, TINY_META, resume=True)
        _tiny_chunk(first)
        first.finish(3)
        assert not (root / "writer.lock").exists() and first.closed
        with pytest.raises(ValueError, match="closed"):
            _tiny_chunk(first)
    with DatasetWriter(root, TINY_META, resume=True) as again:  # the lock is free again
        assert again.rows == 3
    assert not (root / "writer.lock").exists()
    with pytest.raises(RuntimeError, match="boom"), DatasetWriter(tmp_path / "other", TINY_META):
        raise RuntimeError("boom")
    assert not (tmp_path / "other" / "writer.lock").exists()  # released on exception


ROUNDS = 20


def _contend(root, seed, barrier, results):
    for k in range(ROUNDS):
        barrier.wait(timeout=60)
        try:
            writer = DatasetWriter(root / f"round{k}", {**TINY_META, "seed": seed})
            outcome = "won"
        except DirectoryLockedError as err:
            writer, outcome = None, f"refused: {err}"
        barrier.wait(timeout=60)  # both have tried before the winner writes and lets go
        if writer is not None:
            _tiny_chunk(writer, value=seed)
            writer.finish(3)
        results.put((k, seed, outcome))


def test_concurrent_writers_one_wins_and_the_other_is_refused(tmp_path):
    ctx = multiprocessing.get_context("fork")
    barrier, results = ctx.Barrier(2), ctx.Queue()
    procs = [ctx.Process(target=_contend, args=(tmp_path, seed, barrier, results)) for seed in (1, 2)]
    for p in procs:
        p.start()
    outcomes = [results.get(timeout=120) for _ in range(2 * ROUNDS)]
    for p in procs:
        p.join(timeout=60)
        assert p.exitcode == 0
    for k in range(ROUNDS):
        mine = sorted((seed, o) for kk, seed, o in outcomes if kk == k)
        winners = [seed for seed, o in mine if o == "won"]
        losers = [o for _, o in mine if o != "won"]
        assert len(winners) == 1 and len(losers) == 1, mine
        assert "is being written by pid" in losers[0] and f"round{k}" in losers[0]
        ds = TransitionDataset.load(tmp_path / f"round{k}")
        assert ds.metadata["seed"] == winners[0] and (ds.columns["q.j"] == winners[0]).all()


def _dead_pid():
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_a_stale_lock_is_taken_over_with_a_warning(tmp_path, caplog):
    root = tmp_path / "ds"
    root.mkdir()
    stale = {"pid": _dead_pid(), "host": socket.gethostname(), "since": "then", "token": "x"}
    (root / "writer.lock").write_text(json.dumps(stale))
    with caplog.at_level("WARNING", logger="pal.io.locks"), DatasetWriter(root, TINY_META) as writer:
        assert json.loads((root / "writer.lock").read_text())["pid"] == os.getpid()
        _tiny_chunk(writer)
        writer.finish(3)
    assert f"taking over the stale lock {root / 'writer.lock'} of pid {stale['pid']}" in caplog.text
    # a lock held on another host, or an unreadable one, cannot be judged: refused, with the fix
    (root / "writer.lock").write_text(json.dumps({**stale, "host": "elsewhere"}))
    with pytest.raises(DirectoryLockedError, match=r"host 'elsewhere'.*delete .*writer\.lock and retry"):
        DatasetWriter(root, TINY_META, resume=True)
    (root / "writer.lock").write_text("")
    with pytest.raises(DirectoryLockedError, match=r"unreadable.*delete .*writer\.lock"):
        DatasetWriter(root, TINY_META, resume=True)


# ---------------------------------------------------------------------------- chunk manifest
def test_metadata_holds_a_run_id_and_a_chunk_manifest(written):
    root, ds = written
    meta = ds.metadata
    assert len(meta["run_id"]) == 32 and [c["rows"] for c in meta["chunks"]] == [60, 60, 60, 60, 10]
    for entry in meta["chunks"]:
        cmeta, _ = read_chunk(root / entry["file"])
        assert cmeta["run_id"] == meta["run_id"] and cmeta["checksum"] == entry["checksum"]
        assert cmeta["start"] == entry["start"]


def test_a_deleted_last_chunk_of_a_complete_dataset_is_refused(written, tmp_path):
    root = _copy(written[0], tmp_path)
    (root / "chunk_000004.npz").unlink()  # 240 rows left where the metadata says 250
    with pytest.raises(DatasetFileError, match=r"chunk_000004\.npz is missing: .*rows \[240, 250\)"):
        TransitionDataset.load(root)
    with pytest.raises(DatasetFileError, match=r"chunk_000004\.npz is missing"):
        babble(SMALL, root, resume=True)


def test_a_chunk_of_another_run_is_refused(written, tmp_path):
    root = _copy(written[0], tmp_path)
    other = tmp_path / "other"
    babble(SMALL, other)  # the same configuration and seed: equal rows, another run id
    shutil.copy(other / "chunk_000002.npz", root / "chunk_000002.npz")
    with pytest.raises(DatasetFileError, match=r"chunk_000002\.npz belongs to run [0-9a-f]{32}, not to"):
        TransitionDataset.load(root)
    # resuming on top of a foreign last chunk
    partial = tmp_path / "partial"
    babble(BabbleConfig(**{**SMALL.__dict__, "steps": 120}), partial)  # chunks 0 and 1
    shutil.copy(other / "chunk_000002.npz", partial / "chunk_000002.npz")
    with pytest.raises(DatasetFileError, match=r"chunk_000002\.npz belongs to run"):
        babble(SMALL, partial, resume=True)


def test_a_replaced_chunk_of_the_same_run_is_refused(written, tmp_path):
    root = _copy(written[0], tmp_path)
    f = read_npz(root / "chunk_000001.npz", format=data_module.CHUNK_FORMAT)
    arrays = {**f.arrays, "q.finger": f.arrays["q.finger"] + 1}
    write_npz(root / "chunk_000001.npz", arrays, f.meta, format=data_module.CHUNK_FORMAT)  # valid, other rows
    with pytest.raises(DatasetFileError, match=r"chunk_000001\.npz does not match the manifest.*replaced"):
        TransitionDataset.load(root)


def test_a_chunk_written_just_before_an_interruption_is_adopted(written, tmp_path, monkeypatch):
    _, full = written
    root = tmp_path / "run"
    real = DatasetWriter._write_metadata

    def crash_after_third_chunk(self):
        if len(self._chunks) == 3:
            raise KeyboardInterrupt("killed between the chunk and the manifest")
        real(self)

    monkeypatch.setattr(DatasetWriter, "_write_metadata", crash_after_third_chunk)
    with pytest.raises(KeyboardInterrupt):
        babble(SMALL, root)
    monkeypatch.undo()
    assert len(json.loads((root / "metadata.json").read_text())["chunks"]) == 2
    with pytest.raises(
        DatasetFileError, match=r"run is incomplete: its chunks hold 180 of the 250 planned rows"
    ):
        TransitionDataset.load(root)
    partial = TransitionDataset.load(root, allow_incomplete=True)
    assert len(partial) == 180  # chunk 2 belongs to the run and follows on
    assert (partial.complete, partial.planned_rows) == (False, 250) and "rows=180 of 250 planned" in repr(
        partial
    )
    assert_same_rows(babble(SMALL, root, resume=True), full)


# ---------------------------------------------------------------------------- metadata integrity
def _edit_metadata(root, checksum: bool = True, **changes):
    meta = {**json.loads((root / "metadata.json").read_text()), **changes}
    if checksum:
        meta["metadata_checksum"] = metadata_checksum(meta)
    (root / "metadata.json").write_text(json.dumps(meta))


def test_an_edited_metadata_file_is_refused_on_load_and_by_the_dataset_check(written, tmp_path):
    from pal.experiments.world_model.data import DataConfig

    root = _copy(written[0], tmp_path)
    _edit_metadata(root, checksum=False, frame_skip=5)
    with pytest.raises(
        DatasetFileError, match=r"metadata\.json: metadata_checksum '[0-9a-f]{64}' does not match"
    ):
        TransitionDataset.load(root)
    with pytest.raises(DatasetFileError, match=r"metadata\.json: metadata_checksum"):
        DataConfig(dataset=str(root))
    _edit_metadata(root, frame_skip=50)  # the original value, checksum rewritten
    assert len(TransitionDataset.load(root)) == 250


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("columns", [{}], r"'columns' is \[\{\}\], expected a list of column names"),
        ("columns", "q.finger", r"'columns' is 'q.finger', expected a list"),
        ("run_id", 3, r"'run_id' is 3, expected the run id"),
        ("chunks", {"a": 1}, r"'chunks' is \{'a': 1\}, expected the chunk manifest"),
        ("frame_skip", "50", r"'frame_skip' is '50', expected an int >= 1"),
        ("frame_skip", 0, r"'frame_skip' is 0, expected an int >= 1"),
        ("n_rows", 2.5, r"'n_rows' is 2\.5, expected an int >= 0"),
        ("complete", 1, r"'complete' is 1, expected true or false"),
        ("joints", ["finger", 3], r"'joints' is \['finger', 3\], expected a list of names"),
    ],
)
def test_metadata_of_the_wrong_schema_is_refused_naming_file_key_and_value(
    written, tmp_path, key, value, match
):
    root = _copy(written[0], tmp_path)
    _edit_metadata(root, **{key: value})
    with pytest.raises(DatasetFileError, match=r"metadata\.json: " + match):
        TransitionDataset.load(root)


def test_a_manifest_entry_of_the_wrong_types_is_refused(written, tmp_path):
    root = _copy(written[0], tmp_path)
    chunks = json.loads((root / "metadata.json").read_text())["chunks"]
    _edit_metadata(root, chunks=[{**chunks[0], "rows": "60"}, *chunks[1:]])
    with pytest.raises(DatasetFileError, match=r"metadata\.json: 'chunks\[0\]' is .*'rows': '60'"):
        TransitionDataset.load(root)


@pytest.mark.parametrize(
    ("key", "change", "match"),
    [
        (
            "q.finger",
            lambda a: np.repeat(a, 3, axis=1),
            r"array 'q.finger' has shape \(60, 3\) and dtype float32, expected \(60, 1\) float32",
        ),
        (
            "q.finger",
            lambda a: a.astype(np.float64),
            r"array 'q.finger' has shape \(60, 1\) and dtype float64",
        ),
        (
            "state",
            lambda a: a[:, :2],
            r"array 'state' has shape \(60, 2\) and dtype float64, expected \(60, 4\)",
        ),
        ("step", lambda a: a[:, None], r"array 'step' has shape \(60, 1\)"),
    ],
)
def test_a_chunk_array_of_the_wrong_shape_is_refused_naming_the_chunk(written, tmp_path, key, change, match):
    root = _copy(written[0], tmp_path)
    path = root / "chunk_000001.npz"
    f = read_npz(path, format=data_module.CHUNK_FORMAT)
    write_npz(path, {**f.arrays, key: change(f.arrays[key])}, f.meta, format=data_module.CHUNK_FORMAT)
    checksum = read_chunk(path)[0]["checksum"]
    chunks = json.loads((root / "metadata.json").read_text())["chunks"]
    chunks[1]["checksum"] = checksum  # a consistent file and manifest, of the wrong shape
    _edit_metadata(root, chunks=chunks)
    with pytest.raises(DatasetFileError, match=r"chunk_000001\.npz: " + match):
        TransitionDataset.load(root)
