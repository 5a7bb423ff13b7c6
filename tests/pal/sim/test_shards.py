"""Parallel babbling: seeded shards in local processes, merged atomically into one dataset."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pal.cli import main
from pal.io.dataset import METADATA, TransitionDataset
from pal.sim.babbling import BabbleConfig, babble, collect
from pal.sim.shards import babble_sharded, shard_configs, shard_seed

CONFIG = BabbleConfig(body="finger", seed=5, steps=23, frame_skip=5, reset_every=7, chunk_size=6)


def _assert_same(a: TransitionDataset, b: TransitionDataset) -> None:
    assert np.array_equal(a.states, b.states) and np.array_equal(a.ctrl, b.ctrl)
    assert np.array_equal(a.step, b.step) and np.array_equal(a.episode, b.episode)
    assert a.columns.keys() == b.columns.keys()
    assert all(np.array_equal(a.columns[k], b.columns[k]) for k in a.columns)


def _serial_reference(config: BabbleConfig, workers: int) -> list[TransitionDataset]:
    return [collect(c) for c in shard_configs(config, workers)]


def test_shards_split_the_steps_and_derive_their_seeds():
    shards = shard_configs(CONFIG, 3)
    assert [c.steps for c in shards] == [8, 8, 7]
    assert [c.seed for c in shards] == [shard_seed(5, k) for k in range(3)]
    assert len({c.seed for c in shards} | {CONFIG.seed}) == 4


@pytest.mark.slow
def test_sharded_run_in_processes_equals_the_shards_run_serially(tmp_path):
    merged = babble_sharded(CONFIG, tmp_path / "out", workers=2)
    parts = _serial_reference(CONFIG, 2)
    assert len(merged) == CONFIG.steps and merged.metadata["complete"]
    assert [s["start"] for s in merged.metadata["shards"]] == [0, len(parts[0])]
    assert np.array_equal(merged.states, np.concatenate([p.states for p in parts]))
    assert np.array_equal(merged.ctrl, np.concatenate([p.ctrl for p in parts]))
    for key in merged.columns:
        assert np.array_equal(merged.columns[key], np.concatenate([p.columns[key] for p in parts])), key
    assert np.array_equal(merged.step, np.arange(CONFIG.steps))  # offsets keep steps and episodes unique
    assert (
        np.all(np.diff(merged.episode) >= 0) and merged.episode[len(parts[0])] == parts[0].episode.max() + 1
    )
    assert not (tmp_path / "out" / ".merging").exists()


def test_an_interrupted_sharded_run_resumes_per_shard(tmp_path):
    out = tmp_path / "out"
    reference = babble_sharded(CONFIG, tmp_path / "ref", workers=2, processes=False)
    first = shard_configs(CONFIG, 2)[0]
    babble(replace(first, steps=6), out / "shards" / "shard_000")  # shard 0 stopped after one chunk
    (out / ".merging").mkdir()  # and a merge that never finished
    assert not (out / METADATA).exists()
    with pytest.raises(ValueError, match="already holds a dataset or shards; pass resume=True"):
        babble_sharded(CONFIG, out, workers=2, processes=False)
    _assert_same(babble_sharded(CONFIG, out, workers=2, resume=True, processes=False), reference)
    _assert_same(TransitionDataset.load(out), reference)
    with pytest.raises(ValueError, match="holds a run over workers=2; it cannot be resumed with workers=3"):
        babble_sharded(CONFIG, out, workers=3, resume=True, processes=False)
    babble(CONFIG, tmp_path / "plain")
    with pytest.raises(ValueError, match="holds a single-process dataset; it cannot be resumed"):
        babble_sharded(CONFIG, tmp_path / "plain", workers=2, resume=True, processes=False)


def test_bad_worker_counts_get_one_line_errors(tmp_path, capsys):
    with pytest.raises(ValueError, match="workers must be a positive int, got 0"):
        shard_configs(CONFIG, 0)
    with pytest.raises(ValueError, match="workers=24 exceeds steps=23"):
        shard_configs(CONFIG, 24)
    with pytest.raises(ValueError, match="effective_range cannot be split"):
        shard_configs(replace(CONFIG, effective_range=True), 2)
    out = tmp_path / "cli"
    assert main(["babble", "--workers", "0", "--steps", "10", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "pal babble: --workers must be >= 1, got 0" and not out.exists()


def _children(pid: int) -> dict[int, str]:
    """pid -> command line of the live (not zombie) processes whose parent is ``pid``, from /proc."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:  # ended while listed
            continue
        state, ppid = stat.rsplit(")", 1)[1].split()[:2]
        if int(ppid) == pid and state != "Z":
            found[int(entry.name)] = cmdline
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_workers_exit_when_the_babbling_process_is_killed(tmp_path):
    root = Path(__file__).resolve().parents[3]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
    argv = [
        "babble",
        "--workers",
        "2",
        "--steps",
        "2000000",
        "--frame-skip",
        "1",
        "--out",
        str(tmp_path / "d"),
    ]
    parent = subprocess.Popen([sys.executable, "-m", "pal.cli", *argv], env=env, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60
        workers: dict[int, str] = {}
        while len(workers) < 2 and time.monotonic() < deadline and parent.poll() is None:
            time.sleep(0.2)
            workers = {p: c for p, c in _children(parent.pid).items() if "resource_tracker" not in c}
        assert len(workers) == 2, workers
        time.sleep(1.0)  # the workers are babbling
        parent.kill()
        parent.wait()
        deadline = time.monotonic() + 5
        while any(_alive(p) for p in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [p for p in workers if _alive(p)], workers
    finally:
        parent.kill()
        for p in workers if "workers" in locals() else ():
            if _alive(p):
                os.kill(p, signal.SIGKILL)


_WATCHED = """
import os, subprocess, sys
child = subprocess.Popen([sys.executable, "-c", '''
import os, threading, time
from pal.sim.shards import _watch_parent
threading.Thread(target=_watch_parent, args=(os.getppid(), 0.05), daemon=True).start()
print("watching", flush=True)
time.sleep(60)
'''], stdout=subprocess.PIPE, text=True)
assert child.stdout.readline() == "watching\\n"
print(child.pid, flush=True)
child.wait()
"""


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_without_prctl_the_watcher_thread_ends_the_worker_when_its_parent_dies():
    root = Path(__file__).resolve().parents[3]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
    parent = subprocess.Popen([sys.executable, "-c", _WATCHED], env=env, stdout=subprocess.PIPE, text=True)
    child = int(parent.stdout.readline())
    try:
        assert _alive(child)
        parent.kill()
        parent.wait()
        deadline = time.monotonic() + 5
        while _alive(child) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(child)
    finally:
        if _alive(child):
            os.kill(child, signal.SIGKILL)
