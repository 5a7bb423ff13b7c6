"""Folder naming patterns, stills without fps, partial TUM downloads and interpolated ground truth."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import pal.io.sequence_files as sequence_files
from pal.io.sequence_files import MissingFramesWarning
from pal.perception.folder_layouts import LAYOUTS, FolderLayout
from pal.perception.folders import FolderSequence
from pal.perception.sequence import SequenceError, open_sequence
from pal.perception.tum import TUMSequence

K = np.array([[50.0, 0.0, 15.5], [0.0, 50.0, 11.5], [0.0, 0.0, 1.0]])


def _write(folder, color_name: str, depth_name: str, stems, depth_mm: int = 1000) -> None:
    for k, stem in enumerate(stems):
        c, d = folder / color_name.format(stem=stem), folder / depth_name.format(stem=stem)
        c.parent.mkdir(parents=True, exist_ok=True)
        d.parent.mkdir(parents=True, exist_ok=True)
        assert cv2.imwrite(str(c), np.full((24, 32, 3), 10 * k, np.uint8))
        assert cv2.imwrite(str(d), np.full((24, 32), depth_mm + k, np.uint16))


@pytest.mark.parametrize(
    ("color", "depth", "name"),
    [
        ("{stem}.png", "{stem}_depth.png", "paired"),
        ("{stem}-color.png", "{stem}-depth.png", "dashed"),
        ("color/{stem}.jpg", "depth/{stem}.png", "subfolders"),
        ("rgb/{stem}.png", "depth/{stem}.pgm", "rgb-subfolders"),
    ],
)
def test_the_common_naming_patterns_are_found(tmp_path, color, depth, name):
    _write(tmp_path, color, depth, ["10", "2", "1"])
    seq = open_sequence(tmp_path, K=K, depth_scale=0.001)
    assert isinstance(seq, FolderSequence) and seq.layout == name and seq.stems == ["1", "2", "10"]
    assert seq[2].depth[0, 0] == pytest.approx(1.000, abs=1e-6)  # stem "10" was written first: 1000 mm
    assert seq[0].depth[0, 0] == pytest.approx(1.002, abs=1e-6)


def test_a_custom_pattern_is_read_and_one_that_matches_nothing_is_named(tmp_path):
    _write(tmp_path, "img_{stem}.png", "range/dep_{stem}.png", ["0", "1"])
    with pytest.raises(SequenceError, match="nor a folder of frames"):
        open_sequence(tmp_path, K=K, depth_scale=0.001)
    no_pairs = f"{tmp_path} holds no colour/depth image pairs of a built-in layout"
    with pytest.raises(SequenceError, match=re.escape(no_pairs)) as err:
        FolderSequence(tmp_path, K=K, depth_scale=0.001)
    text = str(err.value)
    for known in LAYOUTS:  # every pattern tried is named, and how to pass another
        assert f"{known.name!r} ({known.describe()})" in text
    assert (
        "'rgb-subfolders' (rgb/{stem}.<ext> + depth/{stem}.<ext>)" in text and "layout=FolderLayout" in text
    )
    mine = FolderLayout("mine", "img_{stem}", "range/dep_{stem}")
    seq = open_sequence(tmp_path, K=K, depth_scale=0.001, layout=mine)  # open_sequence passes it on
    assert seq.layout == "mine" and len(seq) == 2 and seq[1].rgb[0, 0, 0] == 10
    message = f"{tmp_path}: the layout 'dashed' ({{stem}}-color.<ext> + {{stem}}-depth.<ext>) matches no file"
    with pytest.raises(SequenceError, match=re.escape(message)):
        FolderSequence(tmp_path, K=K, depth_scale=0.001, layout="dashed")
    with pytest.raises(ValueError, match="layout 'stripes' is unknown"):
        FolderSequence(tmp_path, K=K, depth_scale=0.001, layout="stripes")


@pytest.mark.parametrize(
    ("color", "depth", "message"),
    [
        ("{stem}", "{stem}", "are both"),
        ("frame", "{stem}_d", "exactly once"),
        ("{stem}{stem}", "{stem}_d", "exactly once"),
        ("../{stem}", "{stem}_d", "without '..'"),
        ("/abs/{stem}", "{stem}_d", "relative to the folder"),
        ("{stem}/c", "{stem}_d", "in the file name"),
    ],
)
def test_bad_templates_are_refused_naming_them(color, depth, message):
    with pytest.raises(ValueError, match=message):
        FolderLayout("bad", color, depth)


def test_colour_and_depth_counts_that_differ_are_named(tmp_path):
    _write(tmp_path, "{stem}-color.png", "{stem}-depth.png", ["1", "2", "3"])
    (tmp_path / "2-depth.png").unlink()
    message = (
        f"{tmp_path}: layout 'dashed' ({{stem}}-color.<ext> + {{stem}}-depth.<ext>) finds 3 colour and "
        "2 depth files; colour without depth: ['2'], depth without colour: []"
    )
    with pytest.raises(SequenceError, match=re.escape(message)):
        open_sequence(tmp_path, K=K, depth_scale=0.001)


def test_stills_need_no_frame_rate(tmp_path):
    _write(tmp_path, "{stem}.png", "{stem}_depth.png", ["a", "b", "c"])
    seq = open_sequence(tmp_path, K=K, depth_scale=0.001)
    assert not seq.timed and seq.timestamps.tolist() == [0.0, 1.0, 2.0] and seq[2].timestamp == 2.0
    assert open_sequence(tmp_path, K=K, depth_scale=0.001, fps=4.0).timestamps.tolist() == [0.0, 0.25, 0.5]


def _tum(tmp_path, n: int, present: int, gt: str | None = None):
    d = tmp_path / "tum"
    rgb, depth = ["# partial download"], []
    for k in range(n):
        t = 10.0 + k / 30
        rgb.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth.append(f"{t + 0.002:.6f} depth/{t + 0.002:.6f}.png")
        if k < present:
            _write(d, f"rgb/{t:.6f}.png", f"depth/{t + 0.002:.6f}.png", [""])
    (d / "rgb.txt").write_text("\n".join(rgb) + "\n")
    (d / "depth.txt").write_text("\n".join(depth) + "\n")
    if gt is not None:
        (d / "groundtruth.txt").write_text(gt)
    return d


def test_a_partial_tum_download_is_refused_or_opened_with_what_is_present(tmp_path):
    d = _tum(tmp_path, n=12, present=5)
    what = (
        f"{d}: 7 of 12 frames paired from rgb.txt and depth.txt have an image missing "
        "(first: 10.166667.png of rgb.txt)"
    )
    with pytest.raises(
        SequenceError, match=re.escape(f"{what}; open a partial download with missing='skip'")
    ):
        TUMSequence(d, K=K, depth_scale=0.001)
    with pytest.warns(MissingFramesWarning, match=re.escape(f"{what}; they are skipped")):
        seq = TUMSequence(d, K=K, depth_scale=0.001, missing="skip")
    assert (len(seq), seq.num_listed) == (5, 12) and seq[4].timestamp == pytest.approx(10 + 4 / 30)
    with pytest.raises(IndexError, match="frame 5 out of range for a sequence of 5 frames"):
        seq[5]
    with pytest.raises(ValueError, match="missing is 'ignore'"):
        TUMSequence(d, K=K, depth_scale=0.001, missing="ignore")


def test_skipping_every_frame_is_refused(tmp_path):
    d = _tum(tmp_path / "none", n=3, present=1)
    (d / "rgb" / "10.000000.png").unlink()
    message = (
        f"{d}: 3 of 3 frames paired from rgb.txt and depth.txt have an image missing "
        "(first: 10.000000.png of rgb.txt); missing='skip' leaves no frames"
    )
    with pytest.raises(SequenceError, match=re.escape(message)):
        open_sequence(d, K=K, depth_scale=0.001, missing="skip")


def test_lists_that_pair_no_images_are_named(tmp_path):
    d = _tum(tmp_path, n=3, present=3)  # each depth image 2 ms after its colour image
    message = f"{d}: no image of rgb.txt has one of depth.txt within 0.001 s (max_difference)"
    with pytest.raises(SequenceError, match=re.escape(message)):
        TUMSequence(d, K=K, depth_scale=0.001, max_difference=0.001)
    assert len(TUMSequence(d, K=K, depth_scale=0.001, max_difference=0.003)) == 3


def _gt_rows(times, angles_deg, x) -> str:
    rows = ["# t tx ty tz qx qy qz qw"]
    for t, a, tx in zip(times, angles_deg, x, strict=True):
        q = Rotation.from_euler("z", a, degrees=True).as_quat()
        rows.append(f"{t:.6f} {tx} 0 0 " + " ".join(f"{v:.12f}" for v in q))
    return "\n".join(rows) + "\n"


def test_ground_truth_is_interpolated_and_frames_before_it_are_marked_invalid(tmp_path):
    # mocap starts 0.06 s after the first image, at 100 Hz (as TUM's), turning 90 deg/s about z
    gt_t = np.arange(10.06, 10.2, 0.01)
    d = _tum(tmp_path, n=4, present=4, gt=_gt_rows(gt_t, 90 * (gt_t - 10), gt_t - 10))
    seq = TUMSequence(d, K=K, depth_scale=0.001)
    poses = seq.camera_poses()
    assert poses.valid.tolist() == [False, False, True, True]
    assert np.allclose(poses.poses[0], np.eye(4))
    for k in (2, 3):
        angle = Rotation.from_matrix(poses.poses[k][:3, :3]).as_euler("xyz", degrees=True)[2]
        # slerp, not the nearest sample
        assert angle == pytest.approx(90 * (seq.timestamps[k] - 10), abs=1e-6)
        assert poses.poses[k][0, 3] == pytest.approx(seq.timestamps[k] - 10, abs=1e-9)


def test_ground_truth_that_covers_no_frame_is_refused(tmp_path):
    d = _tum(tmp_path, n=3, present=3, gt=_gt_rows([20.0, 20.01], [0, 1], [0, 0]))
    seq = TUMSequence(d, K=K, depth_scale=0.001)
    gt = d / "groundtruth.txt"
    message = (
        f"{gt}: its 2 poses (20.000-20.010 s) cover none of the 3 frames (10.000-10.067 s) within 0.02 s"
    )
    with pytest.raises(SequenceError, match=re.escape(message)):
        seq.camera_poses()
    shifted = (
        f"{gt}: its 2 poses (20.000-20.010 s) cover none of the 3 frames "
        "(10.050-10.117 s with offset +0.050 s) within 0.02 s"
    )
    with pytest.raises(SequenceError, match=re.escape(shifted)):
        seq.camera_poses(offset=0.05)
    (d / "groundtruth.txt").write_text(_gt_rows([10.0, 10.0], [0, 1], [0, 0]))
    with pytest.raises(SequenceError, match="have the same time"):
        seq.groundtruth()


def test_oversized_lists_are_refused_before_reading(tmp_path, monkeypatch):
    d = _tum(tmp_path, n=3, present=3)
    monkeypatch.setattr(sequence_files, "MAX_TEXT_BYTES", 64)
    with pytest.raises(SequenceError, match=r"rgb\.txt is \d+ bytes, more than the 64"):
        TUMSequence(d, K=K, depth_scale=0.001)
