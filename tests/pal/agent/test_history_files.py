"""The agent's history and perception's trajectories persist through pal.io.files, with provenance."""

from __future__ import annotations

import json
import struct
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from pal.agent.history import FORMAT, History
from pal.io.files import FileFormatError, read_npz, write_npz
from pal.perception.trajectory import Pose, PoseDiagnostics, Trajectory


def _history(n: int = 3) -> History:
    h = History(("shoulder",), ("box",), provenance={"seed": 5})
    for k in range(n):
        missing = np.full((1, 2), np.nan) if k == 1 else np.zeros((1, 2))
        h.append(
            episode=0,
            act=[0.1 * k],
            q_prev=[0.0],
            q=[0.1],
            hand_prev=[0, 0, 0],
            hand=[0, 0, 0.01],
            touch=[0.0],
            meas_prev=missing,
            meas=missing,
            std=missing,
            est_prev=np.zeros((1, 2)),
            est=np.zeros((1, 2)),
            truth_prev=np.zeros((1, 2)),
            truth=np.zeros((1, 2)),
            state=np.arange(4.0),
        )
    return h


def _damage(path: Path, member: str, mask: int) -> None:
    """Flip bits in the middle of one zip member's compressed data (which the zip CRC covers)."""
    raw = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        info = z.getinfo(member)
    name_len, extra_len = struct.unpack("<HH", raw[info.header_offset + 26 : info.header_offset + 30])
    data = info.header_offset + 30 + name_len + extra_len
    raw[data + info.compress_size // 2] ^= mask
    path.write_bytes(bytes(raw))


@dataclass(frozen=True)
class _Config:
    steps: int = 3
    lr: float = 0.01


def test_history_save_records_provenance_versions_and_format(tmp_path):
    h = _history()
    path = h.save(tmp_path / "h.npz", {"note": "x"}, config=_Config())
    loaded, meta = History.load(path)
    assert meta["provenance"] == {"seed": 5, "config": {"steps": 3, "lr": 0.01}} == loaded.provenance
    assert meta["note"] == "x" and meta["format"] == FORMAT and "numpy" in meta["versions"]
    for field in ("act", "meas", "state", "episode"):
        np.testing.assert_array_equal(loaded.array(field), h.array(field))  # NaN stays NaN in arrays
    assert np.isnan(loaded.array("meas")[1]).all()
    assert read_npz(path, format=FORMAT).meta["joints"] == ["shoulder"]
    path = h.save(tmp_path / "h2.npz", seed=9)
    assert History.load(path)[1]["provenance"]["seed"] == 9
    empty, _ = History.load(History(("a",), ()).save(tmp_path / "e.npz"))
    assert len(empty) == 0 and empty.joints == ("a",)


def test_history_save_refuses_nan_metadata_and_reserved_keys(tmp_path):
    h = _history()
    with pytest.raises(ValueError, match=r"history metadata\['provenance'\]\['config'\]\['lr'\] is nan"):
        h.save(tmp_path / "h.npz", config={"lr": float("nan")})
    with pytest.raises(ValueError, match="reserved"):
        h.save(tmp_path / "h.npz", {"joints": []})
    assert not (tmp_path / "h.npz").exists()


def test_a_damaged_history_raises_the_documented_error(tmp_path):
    path = _history().save(tmp_path / "h.npz")
    _damage(path, "act.npy", 0x10)
    with pytest.raises(FileFormatError, match=r"h\.npz"):
        History.load(path)
    np.savez(path, _meta=np.frombuffer(json.dumps({"joints": []}).encode(), np.uint8))  # the old layout
    with pytest.raises(FileFormatError, match="no __meta__ entry"):
        History.load(path)


def test_trajectory_files_are_checked(tmp_path):
    traj = Trajectory()
    traj.append(Pose(0.0, "estimated", np.eye(4), PoseDiagnostics(solver="kabsch")))
    traj.append(Pose(0.1, "lost", None))
    path = traj.save(tmp_path / "t.npz", metadata={"object": "box", "seed": 2})
    back, meta = Trajectory.load(path)
    assert [p.source for p in back.poses] == ["estimated", "lost"] and meta["metadata"]["seed"] == 2
    assert meta["format"] == "pal.trajectory/3" and "scipy" in meta["versions"]
    _damage(path, "poses.npy", 0x01)
    with pytest.raises(FileFormatError, match="not a readable trajectory"):
        Trajectory.load(path)
    # The previous format (no covariances, no rejected poses) still reads; an unknown one is refused.
    old = {"timestamps": np.array([0.0]), "source": np.array([1], np.int8), "poses": np.eye(4)[None]}
    diag = {"matches": 0, "pairs": 0, "inliers": 0, "rmse": None, "solver": "kabsch", "reason": ""}
    diag |= {"snapshot": None, "attempts": 0}
    write_npz(tmp_path / "v2.npz", old, {"metadata": {}, "diagnostics": [diag]}, format="pal.trajectory/2")
    back, meta = Trajectory.load(tmp_path / "v2.npz")
    assert meta["format"] == "pal.trajectory/2" and back.poses[0].covariance is None
    np.testing.assert_array_equal(back.poses[0].camera_from_object, np.eye(4))
    write_npz(tmp_path / "v9.npz", old, {"metadata": {}, "diagnostics": [diag]}, format="pal.trajectory/9")
    with pytest.raises(FileFormatError, match="not a readable trajectory"):
        Trajectory.load(tmp_path / "v9.npz")
    with pytest.raises(ValueError, match=r"trajectory metadata\['metadata'\]\['err'\] is inf"):
        traj.save(tmp_path / "u.npz", metadata={"err": float("inf")})
