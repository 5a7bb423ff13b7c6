"""Hostile files of at most 2 MB are refused in bounded memory: deflate bombs and huge images.

Each read runs in a fresh interpreter that reports its own peak resident set size (``VmHWM``
of ``/proc/self/status``, else ``ru_maxrss``); the file must be refused with the documented
error naming it, at a peak under 512 MB.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.hostile import npz_bomb, png_bomb

_LIMIT_MB = 512
_CHILD = """
import json, resource, sys
kind, path = sys.argv[1], sys.argv[2]
try:
    if kind == "model":
        from models.io import load
        load(path)
    elif kind == "chunk":
        from pal.io.dataset_files import read_chunk
        read_chunk(path)
    else:
        import numpy as np
        from pal.perception.tum import TUMSequence
        TUMSequence(path, K=np.eye(3), depth_scale=0.001)[0]
    error, message = None, ""
except Exception as err:
    error, message = type(err).__name__, str(err)
try:  # this process's own high-water mark (ru_maxrss would carry the forking parent's over exec)
    status = open("/proc/self/status").read()
    peak = int(status.split("VmHWM:")[1].split()[0]) / 1024
except (OSError, IndexError):
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps({"error": error, "message": message, "peak_mb": peak}))
"""


def _read_in_child(kind: str, path: Path) -> dict:
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, kind, str(path)], capture_output=True, text=True, timeout=300, env=env
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def _tum_pair(root: Path) -> Path:
    root.mkdir()
    png_bomb(root / "rgb.png")
    png_bomb(root / "depth.png", depth=True)
    (root / "rgb.txt").write_text("1.0 rgb.png\n")
    (root / "depth.txt").write_text("1.0 depth.png\n")
    return root


@pytest.mark.parametrize(
    ("kind", "error", "words"),
    [
        ("model", "ModelFileTooLargeError", "compression ratio"),
        ("chunk", "DatasetFileError", "compression ratio"),
        ("png", "SequenceError", "16000x16000"),
    ],
)
def test_hostile_files_are_refused_in_bounded_memory(tmp_path, kind, error, words):
    if kind == "png":
        path = _tum_pair(tmp_path / "seq")
        assert (path / "rgb.png").stat().st_size + (path / "depth.png").stat().st_size <= 2 * 10**6
    else:
        name = "state/w" if kind == "model" else "state"
        path = npz_bomb(tmp_path / "bomb.npz", name, extra={"__meta__": np.frombuffer(b"{}", np.uint8)})
        assert path.stat().st_size <= 2 * 10**6
    result = _read_in_child(kind, path)
    assert result["error"] == error, result
    assert words in result["message"] and str(tmp_path) in result["message"], result
    assert result["peak_mb"] < _LIMIT_MB, result
