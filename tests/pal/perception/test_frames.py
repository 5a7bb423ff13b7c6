"""RGBDFrame checks, crop intrinsics, and recorded sequences (pal layout and TUM layout)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from pal.perception.folder_layouts import LAYOUTS
from pal.perception.frames import RGBDFrame, backproject, crop_intrinsics, project
from pal.perception.sequence import (
    RecordedSequence,
    SequenceError,
    SequenceWriter,
    encode_depth,
    open_sequence,
)
from pal.perception.synthetic import Box, SyntheticCamera
from pal.perception.tum import FREIBURG2_K, FREIBURG_DEFAULT_K, TUM_DEPTH_SCALE, TUMSequence, associate

K = np.array([[100.0, 0.0, 31.5], [0.0, 100.0, 23.5], [0.0, 0.0, 1.0]])


def frame(h: int = 48, w: int = 64, **kw) -> RGBDFrame:
    args = {
        "rgb": np.zeros((h, w, 3), np.uint8),
        "depth": np.ones((h, w), np.float32),
        "K": K,
        "timestamp": 0.0,
    }
    args.update(kw)
    return RGBDFrame(**args)


def test_valid_frame_is_read_only_and_keeps_zero_as_invalid():
    depth = np.ones((48, 64), np.float32)
    depth[0, 0] = 0.0
    f = frame(depth=depth)
    assert f.shape == (48, 64) and f.height == 48 and f.width == 64
    assert not f.valid_depth()[0, 0] and f.valid_depth()[1, 1]
    with pytest.raises(ValueError):
        f.depth[1, 1] = 2.0  # read-only view
    depth[1, 1] = 3.0  # the caller's array stays writable
    assert f.gray().shape == (48, 64)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"depth": np.ones((40, 64), np.float32)}, r"depth has shape \(40, 64\), expected \(48, 64\)"),
        ({"depth": np.full((48, 64), np.nan, np.float32)}, "NaN/inf"),
        ({"depth": np.full((48, 64), np.inf, np.float32)}, "NaN/inf"),
        ({"depth": -np.ones((48, 64), np.float32)}, "negative"),
        ({"depth": np.ones((48, 64), np.float64)}, "float32"),
        ({"rgb": np.zeros((48, 64, 3), np.float32)}, "uint8"),
        ({"rgb": np.zeros((48, 64), np.uint8)}, r"expected \(H, W, 3\)"),
        ({"rgb": np.zeros((0, 0, 3), np.uint8), "depth": np.zeros((0, 0), np.float32)}, "empty"),
        ({"K": None}, "missing"),
        ({"K": np.eye(2)}, r"expected \(3, 3\)"),
        ({"K": np.diag([0.0, 100.0, 1.0])}, "focal"),
        ({"K": np.array([[100, 0, 1], [0, 100, 1], [0, 1, 1.0]])}, r"K\[2\] = \[0, 0, 1\]"),
        ({"K": np.full((3, 3), np.nan)}, "non-finite"),
        ({"timestamp": float("nan")}, "timestamp"),
        ({"labels": np.zeros((4, 4), np.int32)}, "labels has shape"),
    ],
)
def test_bad_frames_raise_naming_the_problem(kwargs, match):
    with pytest.raises(ValueError, match=match):
        frame(**kwargs)


def test_crop_shifts_the_principal_point():
    cam = SyntheticCamera(64, 48)
    f = cam.render([], 0.0)
    point = np.array([0.05, -0.02, 0.9])
    u, v = project(point, f.K)
    c = f.crop(10, 5, 50, 40)
    assert c.shape == (35, 40)
    assert np.allclose(c.K, crop_intrinsics(f.K, 10, 5))
    uc, vc = project(point, c.K)
    assert uc == pytest.approx(u - 10) and vc == pytest.approx(v - 5)
    # a pixel back-projects to the same 3-D point in the crop and in the full frame
    assert np.allclose(c.points()[20, 30], f.points()[25, 40])
    assert np.allclose(backproject(40.0, 25.0, 1.0, f.K), backproject(30.0, 20.0, 1.0, c.K))
    with pytest.raises(ValueError, match="outside"):
        f.crop(0, 0, 65, 10)


def _render_sequence(n: int = 3) -> list[RGBDFrame]:
    cam = SyntheticCamera(64, 48)
    out = []
    for k in range(n):
        pose = cam.table.copy()
        pose[:3, 3] += [0.01 * k, 0.0, 0.0]
        out.append(cam.render([Box((0.1, 0.1, 0.05), pose, label=3, seed=1)], 0.1 * k))
    return out


def test_sequence_roundtrip_with_ground_truth(tmp_path):
    frames = _render_sequence()
    gt = [np.eye(4) + k for k in range(3)]
    with SequenceWriter(
        tmp_path / "seq", metadata={"seed": 0, "motion": "test"}, label_names={3: "box"}
    ) as w:
        for k, f in enumerate(frames):
            w.append(f, gt_poses={"box": gt[k]} if k != 1 else {})
    seq = open_sequence(tmp_path / "seq")
    assert isinstance(seq, RecordedSequence) and len(seq) == 3
    assert seq.metadata == {"seed": 0, "motion": "test"} and seq.label_names == {3: "box"}
    assert np.allclose(seq.K, frames[0].K)
    for f, g in zip(frames, seq, strict=True):
        assert np.array_equal(f.rgb, g.rgb)
        assert np.abs(f.depth - g.depth).max() <= 0.0005 + 1e-6  # 1 mm quantisation
        assert np.array_equal(f.labels, g.labels)
        assert g.timestamp == pytest.approx(f.timestamp)
    poses, valid = seq.gt_poses("box")
    assert valid.tolist() == [True, False, True]
    assert np.allclose(poses[2], gt[2])
    assert not list((tmp_path / "seq").rglob("*.tmp"))  # atomic writes leave no temp file
    with pytest.raises(KeyError, match="no ground-truth poses"):
        seq.gt_poses("ball")
    assert seq[-1].timestamp == pytest.approx(0.2)
    with pytest.raises(IndexError):
        seq[3]


def test_writer_rejects_inconsistent_frames(tmp_path):
    frames = _render_sequence(1)
    w = SequenceWriter(tmp_path / "a")
    w.append(frames[0])
    with pytest.raises(ValueError, match="size"):
        w.append(frame(h=40))
    other = RGBDFrame(
        frames[0].rgb, frames[0].depth, frames[0].K * np.array([[2, 1, 1], [1, 2, 1], [1, 1, 1]]), 1.0
    )
    with pytest.raises(ValueError, match="intrinsics"):
        w.append(other)
    w.close()
    with pytest.raises(SequenceError, match="already holds a sequence"):
        SequenceWriter(tmp_path / "a")
    with pytest.raises(SequenceError, match="empty sequence"):
        SequenceWriter(tmp_path / "b").close()


def test_depth_beyond_the_scale_range_becomes_invalid():
    units = encode_depth(np.array([[1.0, 70.0]], np.float32), 0.001)
    assert units.tolist() == [[1000, 0]]


def test_unreadable_sequences_raise_clear_errors(tmp_path):
    with pytest.raises(SequenceError, match="does not exist"):
        open_sequence(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(SequenceError, match="neither a pal sequence") as refused:
        open_sequence(tmp_path / "empty")
    assert str(tmp_path / "empty") in str(refused.value)
    assert all(f"'{layout.name}' ({layout.describe()})" in str(refused.value) for layout in LAYOUTS)
    (tmp_path / "partial" / "rgb").mkdir(parents=True)
    with pytest.raises(SequenceError, match=r"sequence\.json does not exist"):
        open_sequence(tmp_path / "partial")
    with SequenceWriter(tmp_path / "ok") as w:
        w.append(_render_sequence(1)[0])
    (tmp_path / "ok" / "depth" / "000000.png").unlink()
    seq = open_sequence(tmp_path / "ok")
    with pytest.raises(SequenceError, match=r"000000\.png does not exist"):
        seq[0]
    (tmp_path / "ok" / "intrinsics.json").write_text(json.dumps({"K": [[0, 0, 0], [0, 0, 0], [0, 0, 1]]}))
    with pytest.raises(SequenceError, match="focal"):
        open_sequence(tmp_path / "ok")
    (tmp_path / "ok" / "sequence.json").write_text("{not json")
    with pytest.raises(SequenceError, match="not readable JSON"):
        open_sequence(tmp_path / "ok")


def test_tum_layout_with_association_scale_and_intrinsics(tmp_path):
    d = tmp_path / "tum"
    (d / "rgb").mkdir(parents=True)
    (d / "depth").mkdir()
    rgb_lines, depth_lines = ["# color images", "# file: test"], ["# depth maps"]
    for k, t in enumerate([1.000, 1.033, 1.066, 1.500]):
        img = np.full((48, 64, 3), 10 * k, np.uint8)
        cv2.imwrite(str(d / "rgb" / f"{t:.6f}.png"), img)
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        if k < 3:  # the last colour image has no depth partner within 20 ms
            td = t + 0.005
            cv2.imwrite(str(d / "depth" / f"{td:.6f}.png"), np.full((48, 64), 5000 * (k + 1), np.uint16))
            depth_lines.append(f"{td:.6f} depth/{td:.6f}.png")
    (d / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (d / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    (d / "groundtruth.txt").write_text("# t tx ty tz qx qy qz qw\n1.001 1 2 3 0 0 0 1\n1.034 4 5 6 0 0 0 1\n")
    with pytest.raises(SequenceError, match="intrinsics are unknown.*no default camera"):
        open_sequence(d)  # no silent default camera
    with pytest.raises(SequenceError, match="depth scale is unknown.*TUM_DEPTH_SCALE"):
        open_sequence(d, K=FREIBURG2_K)
    seq = open_sequence(d, K=FREIBURG2_K, depth_scale=TUM_DEPTH_SCALE)
    assert isinstance(seq, TUMSequence) and len(seq) == 3
    assert np.allclose(seq.K, FREIBURG2_K)
    f = seq[2]
    assert f.depth[0, 0] == pytest.approx(3.0) and f.rgb[0, 0, 0] == 20
    assert f.timestamp == pytest.approx(1.066)
    gt, valid = seq.groundtruth()
    assert valid.tolist() == [True, True, False] and gt[0, :3].tolist() == [
        1,
        2,
        3,
    ]  # nearest, before the first
    w = (1.033 - 1.001) / (1.034 - 1.001)  # interpolated between the two samples
    assert np.allclose(gt[1, :3], [1 + 3 * w, 2 + 3 * w, 3 + 3 * w], atol=1e-9) and gt[2].tolist() == [0] * 7
    (d / "calibration.json").write_text(
        json.dumps({"fx": 100, "fy": 100, "cx": 31.5, "cy": 23.5, "depth_scale": 2e-4})
    )
    custom = TUMSequence(d)  # the calibration file next to the lists
    assert np.allclose(custom.K, K) and custom.depth_scale == pytest.approx(2e-4)
    assert np.allclose(TUMSequence(d, K=FREIBURG_DEFAULT_K).K, FREIBURG_DEFAULT_K)  # arguments win
    poses = custom.camera_poses()  # frames without ground truth are marked, not refused
    assert poses.valid.tolist() == [True, True, False] and np.allclose(poses.poses[2], np.eye(4))
    (d / "rgb.txt").write_text("1.066000 rgb/1.066000.png\n1.000000 rgb/1.000000.png\n")
    with pytest.raises(SequenceError, match="not monotonic: frame 1 at 1.000000 s comes after frame 0"):
        TUMSequence(d)
    (d / "depth.txt").write_text("# nothing\n")
    with pytest.raises(SequenceError, match="lists no images"):
        TUMSequence(d)


def test_association_is_greedy_and_one_to_one():
    pairs = associate(np.array([0.0, 0.01, 0.5]), np.array([0.004, 0.012]), 0.02)
    assert pairs == [(0, 0), (1, 1)]


def test_missing_or_invalid_intrinsics_in_a_sequence_raise(tmp_path):
    with SequenceWriter(tmp_path / "s") as w:
        w.append(_render_sequence(1)[0])
    intr = tmp_path / "s" / "intrinsics.json"
    intr.write_text(json.dumps({"width": 64, "height": 48}))  # no K
    with pytest.raises(SequenceError, match=r"intrinsics\.json: K \(camera intrinsics\) is missing"):
        open_sequence(tmp_path / "s")
    intr.write_text(json.dumps({"K": [[100, 0, 30], [0, 100, 20]]}))
    with pytest.raises(SequenceError, match=r"expected \(3, 3\)"):
        open_sequence(tmp_path / "s")
    intr.unlink()
    with pytest.raises(SequenceError, match=r"intrinsics\.json does not exist"):
        open_sequence(tmp_path / "s")


# ---------------------------------------------------------------------------- the frame contract's home
def test_the_frame_contract_lives_in_pal_frames_and_perception_re_exports_it():
    import pal.frames
    import pal.io.sequence_files
    import pal.perception
    import pal.perception.frames

    assert pal.perception.RGBDFrame is pal.perception.frames.RGBDFrame is pal.frames.RGBDFrame
    assert pal.perception.SequenceWriter is pal.io.sequence_files.SequenceWriter
    assert issubclass(SequenceError, ValueError)


def test_depth_in_millimetres_warns_with_the_range_and_the_fix():
    from pal.frames import DepthUnitsWarning, check_depth_units

    depth_mm = np.full((48, 64), 850.0, np.float32)
    depth_mm[:10] = 0.0  # invalid pixels do not count
    depth_mm[10:20] = 1200.0
    with pytest.warns(
        DepthUnitsWarning, match=r"span 850 to 1200 with median 850.*millimetres.*depth_scale"
    ) as rec:
        frame(depth=depth_mm)
    assert rec[0].filename == __file__  # points at the code that built the frame
    with pytest.warns(DepthUnitsWarning, match=r"centimetres \(0\.85 m\)"):
        assert not check_depth_units(np.full((4, 4), 85.0, np.float32))
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # metres, even with a far invalid-ish background, do not warn
        far = np.ones((48, 64), np.float32)
        far[:5] = 60.0
        frame(depth=far)
        frame(depth=np.zeros((48, 64), np.float32))
        assert check_depth_units(np.full((4, 4), 19.9, np.float32))


def test_a_recording_read_with_the_wrong_depth_scale_warns(tmp_path):
    from pal.frames import DepthUnitsWarning

    with SequenceWriter(tmp_path / "s") as w:
        w.append(_render_sequence(1)[0])
    info = json.loads((tmp_path / "s" / "sequence.json").read_text())
    (tmp_path / "s" / "sequence.json").write_text(json.dumps({**info, "depth_scale": 1.0}))  # "metres"
    with pytest.warns(DepthUnitsWarning, match="depth_scale"):
        open_sequence(tmp_path / "s")[0]


def test_ground_truth_poses_are_a_checked_file(tmp_path):
    frames = _render_sequence(2)
    with SequenceWriter(tmp_path / "s") as w:
        for f in frames:
            w.append(f, gt_poses={"box": np.eye(4)})
    path = tmp_path / "s" / "gt" / "poses.npz"
    raw = bytearray(path.read_bytes())
    raw[len(raw) // 3] ^= 0x55
    path.write_bytes(bytes(raw))
    with pytest.raises(SequenceError, match=r"poses\.npz"):
        open_sequence(tmp_path / "s")
    np.savez(path, box=np.zeros((2, 4, 4)), **{"box.valid": np.ones(2, bool)})  # an unchecked plain npz
    with pytest.raises(SequenceError, match="no __meta__ entry"):
        open_sequence(tmp_path / "s")
    info = json.loads((tmp_path / "s" / "sequence.json").read_text())
    (tmp_path / "s" / "sequence.json").write_text(json.dumps({**info, "format": "pal.rgbd-sequence/1"}))
    with pytest.raises(SequenceError, match="older layout; record the sequence again"):
        open_sequence(tmp_path / "s")


def test_sequence_metadata_refuses_nan_naming_the_key(tmp_path):
    with pytest.raises(ValueError, match=r"sequence metadata\['noise'\] is nan"):
        SequenceWriter(tmp_path / "s", metadata={"noise": float("nan")})
