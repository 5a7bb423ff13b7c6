"""The single-writer lock: a lock file naming a pid that no process can have."""

from __future__ import annotations

import json
import os
import socket

import pytest

from pal.io.locks import DirectoryLock, pid_alive


@pytest.mark.parametrize("pid", [2**31, 2**40, 2**64])
def test_a_lock_of_a_pid_past_any_real_one_is_stale_and_taken_over_by_name(pid, tmp_path, caplog):
    assert pid_alive(pid) is False
    (tmp_path / "writer.lock").write_text(
        json.dumps({"pid": pid, "host": socket.gethostname(), "since": "then", "token": "x"})
    )
    with caplog.at_level("WARNING", logger="pal.io.locks"), DirectoryLock(tmp_path) as lock:
        assert lock.held and json.loads(lock.path.read_text())["pid"] == os.getpid()
    assert f"taking over the stale lock {tmp_path / 'writer.lock'} of pid {pid}" in caplog.text
    assert not (tmp_path / "writer.lock").exists()
