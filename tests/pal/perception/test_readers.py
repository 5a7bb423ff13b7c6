"""Readers of real RGB-D frames: folder layouts, PGM and 16-bit PNG depth, calibration files, bad input."""

from __future__ import annotations

import json
import re
import shutil
import warnings

import cv2
import numpy as np
import pytest

from pal.frames import DepthUnitsWarning, EmptyDepthError, RGBDFrame, TimestampOrderError, check_depth_range
from pal.perception import Pipeline, PipelineConfig
from pal.perception.folders import FolderSequence
from pal.perception.samples import SAMPLES, open_sample, sample_path, support_regions
from pal.perception.sequence import SequenceError, open_sequence

DESK_K = [[520.9, 0.0, 325.1], [0.0, 521.0, 249.7], [0.0, 0.0, 1.0]]


def test_the_samples_read_as_rgb_metres_with_their_calibration():
    desk, room = open_sample("tum_desk"), open_sample("kinect_room")
    assert (desk.layout, len(desk), room.layout, len(room)) == ("paired", 2, "subfolders", 3)
    assert np.allclose(desk.K, DESK_K) and desk.depth_scale == pytest.approx(1 / 5000)
    assert room.depth_scale == pytest.approx(0.001) and room.stems == ["3", "4", "5"]
    f = room[0]  # a 16-bit PNG, millimetres
    assert f.shape == (480, 640) and f.depth.dtype == np.float32
    assert 2.0 < float(np.median(f.depth[f.depth > 0])) < 4.0  # a room, seen from 1.4 m
    bgr = cv2.imread(str(sample_path("kinect_room") / "color" / "3.jpg"))
    assert np.array_equal(f.rgb, bgr[..., ::-1])  # channel order: RGB, not OpenCV's BGR
    assert np.array_equal(RGBDFrame.from_bgr(bgr, f.depth, f.K, 0.0).rgb, f.rgb)
    d = desk[1]  # a 16-bit PNG, 1/5000 m
    assert 1.0 < float(np.median(d.depth[d.depth > 0])) < 2.0 and d.timestamp == pytest.approx(1 / 30)
    poses, valid = room.camera_poses()
    assert valid.tolist() == [True] * 3 and poses.shape == (3, 4, 4) and np.allclose(poses[:, 3], [0, 0, 0, 1])
    assert np.allclose(poses[0, :3, :3] @ poses[0, :3, :3].T, np.eye(3))
    with pytest.raises(SequenceError, match="no camera poses"):
        desk.camera_poses()
    assert set(SAMPLES) == {"tum_desk", "kinect_room"} and support_regions("tum_desk")[0] == "desk"
    with pytest.raises(ValueError, match="unknown sample"):
        sample_path("kitchen")


def _copy(tmp_path, name: str, calibration: bool = True):
    src = sample_path(name)
    dst = tmp_path / name
    shutil.copytree(src, dst)
    if not calibration:
        (dst / "calibration.json").unlink()
    return dst


def test_paired_and_subfolder_layouts_need_a_camera_but_no_list(tmp_path):
    desk = _copy(tmp_path, "tum_desk", calibration=False)
    with pytest.raises(SequenceError, match="intrinsics are unknown.*no default camera"):
        open_sequence(desk)
    with pytest.raises(SequenceError, match=r"depth scale is unknown.*0\.0002 for TUM"):
        open_sequence(desk, K=np.array(DESK_K))
    stills = open_sequence(desk, K=np.array(DESK_K), depth_scale=1 / 5000)  # no fps needed
    assert not stills.timed and stills.timestamps.tolist() == [0.0, 1.0]
    seq = open_sequence(desk, K=np.array(DESK_K), depth_scale=1 / 5000, fps=10.0)
    assert isinstance(seq, FolderSequence) and seq.timed and seq.timestamps.tolist() == [0.0, 0.1]
    (desk / "timestamps.txt").write_text("# stem seconds\n1 5.0\n2 4.0\n")
    with pytest.raises(SequenceError, match="not monotonic: frame 1 at 4.000000 s comes after frame 0"):
        open_sequence(desk, K=np.array(DESK_K), depth_scale=1 / 5000)
    (desk / "timestamps.txt").write_text("1 5.0\n2 5.5\n")
    assert open_sequence(desk, K=np.array(DESK_K), depth_scale=1 / 5000).timestamps.tolist() == [5.0, 5.5]
    (desk / "calibration.json").write_text(json.dumps({"fx": 520.9, "fy": 521.0, "cx": 325.1}))
    with pytest.raises(SequenceError, match=r"lacks \['cy'\]"):
        open_sequence(desk)
    with pytest.raises(SequenceError, match="depth_scale is -1, expected a finite number > 0"):
        open_sequence(desk, K=np.array(DESK_K), depth_scale=-1)
    with pytest.raises(SequenceError, match=r"depth_scale is 0\.0, expected a finite number > 0"):
        open_sequence(desk, K=np.array(DESK_K), depth_scale=0.0)


def test_bad_files_raise_naming_the_file(tmp_path):
    room = _copy(tmp_path, "kinect_room")
    png = open_sequence(room)
    depths = [png[k].depth for k in range(len(png))]
    for stem in png.stems:  # the original's 16-bit binary PGM depth files
        depth = room / "depth" / f"{stem}.png"
        assert cv2.imwrite(str(room / "depth" / f"{stem}.pgm"), cv2.imread(str(depth), cv2.IMREAD_UNCHANGED))
        depth.unlink()
    seq = open_sequence(room)
    assert (room / "depth" / "3.pgm").read_bytes().startswith(b"P5")
    assert all(np.array_equal(seq[k].depth, depths[k]) for k in range(len(seq)))
    small = cv2.imread(str(room / "color" / "4.jpg"))[:240, :320]
    cv2.imwrite(str(room / "color" / "4.jpg"), small)
    with pytest.raises(SequenceError, match=r"4\.jpg is 320x240 but 4\.pgm is 640x480"):
        seq[1]
    (room / "depth" / "5.pgm").write_bytes(b"P5 640 480 65535\n" + bytes(640 * 480 * 2))
    with pytest.raises(EmptyDepthError, match=r"5\.pgm has no valid depth pixel"):
        seq[2]
    cv2.imwrite(str(room / "depth" / "3.pgm"), np.zeros((480, 640), np.uint8) + 3)
    with pytest.raises(SequenceError, match=r"3\.pgm has shape \(480, 640\) dtype uint8"):
        seq[0]


def test_implausible_depth_scales_warn_naming_the_likely_fix(tmp_path):
    with pytest.warns(DepthUnitsWarning, match=r"closer than 0\.35 m.*millimetres.*depth_scale=0\.001"):
        open_sequence(sample_path("kinect_room"), depth_scale=1 / 5000)  # a Kinect read as TUM
    with pytest.warns(DepthUnitsWarning, match=r"farther than .* 15 m.*TUM RGB-D.*depth_scale=0\.0002"):
        open_sequence(sample_path("tum_desk"), depth_scale=0.001)  # TUM read as millimetres
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        open_sample("tum_desk"), open_sample("kinect_room")
        assert check_depth_range(np.zeros((4, 4), np.uint16), 0.001)
    with pytest.raises(ValueError, match="depth_scale is 0"):
        check_depth_range(np.ones((4, 4), np.uint16), 0.0)


def test_the_pipeline_refuses_bad_frames_before_changing_state():
    f = open_sample("tum_desk")[0]
    pipe = Pipeline(PipelineConfig(estimate_pose=False, relations=None))
    with pytest.raises(EmptyDepthError, match="no valid depth pixel"):
        pipe(RGBDFrame(f.rgb, np.zeros_like(f.depth), f.K, 0.0))
    assert pipe.frame_count == 0
    pipe(RGBDFrame(f.rgb, f.depth, f.K, 1.0))
    with pytest.raises(TimestampOrderError, match=r"0\.5 s is earlier than the previous frame's 1\.0 s"):
        pipe(RGBDFrame(f.rgb, f.depth, f.K, 0.5))
    assert pipe.frame_count == 1
    with pytest.raises(ValueError, match="missing"):
        RGBDFrame(f.rgb, f.depth, None, 0.0)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"depth has shape \(240, 320\), expected \(480, 640\)"):
        RGBDFrame(f.rgb, f.depth[:240, :320], f.K, 0.0)


# ---------------------------------------------------------------------------- hostile and malformed files
def _tum(tmp_path, rgb_lines: str):
    d = tmp_path / "tum"
    d.mkdir()
    cv2.imwrite(str(d / "a.png"), np.zeros((8, 8, 3), np.uint8))
    cv2.imwrite(str(d / "d.png"), np.full((8, 8), 1000, np.uint16))
    (d / "rgb.txt").write_text(rgb_lines)
    (d / "depth.txt").write_text("1.0 d.png\n")
    return d


@pytest.mark.parametrize(
    ("line", "name"),
    [
        ("1.0 ../outside/x.png", "../outside/x.png"),
        ("1.0 /etc/passwd", "/etc/passwd"),
        ("1.0 link.png", "link.png"),
    ],
)
def test_tum_lists_may_only_name_files_inside_their_folder(tmp_path, line, name):
    (tmp_path / "outside").mkdir()
    cv2.imwrite(str(tmp_path / "outside" / "x.png"), np.zeros((8, 8, 3), np.uint8))
    d = _tum(tmp_path, f"# colour\n{line}\n")
    (d / "link.png").symlink_to(tmp_path / "outside" / "x.png")
    with pytest.raises(
        SequenceError,
        match=rf"rgb\.txt:2: the file '{re.escape(name)}' resolves to .*outside the sequence folder",
    ):
        open_sequence(d, K=np.array(DESK_K), depth_scale=0.001)
    (d / "rgb.txt").write_text("1.0 ./a.png\n")
    assert len(open_sequence(d, K=np.array(DESK_K), depth_scale=0.001)) == 1


def test_tum_lists_refuse_duplicate_timestamps_naming_the_lines(tmp_path):
    d = _tum(tmp_path, "1.0 a.png\n# again\n1.000 a.png\n")
    with pytest.raises(
        SequenceError, match=r"rgb\.txt:3: timestamp 1\.000 is listed twice \(lines 1 and 3\)"
    ):
        open_sequence(d, K=np.array(DESK_K), depth_scale=0.001)
    (d / "rgb.txt").write_bytes(b"1.0 a.png\n\xff\xfe\n")
    with pytest.raises(SequenceError, match=r"rgb\.txt is not a readable text file"):
        open_sequence(d, K=np.array(DESK_K), depth_scale=0.001)


def test_image_sizes_are_read_from_the_header_and_checked_before_decoding(tmp_path):
    from pal.io.image_headers import ImageHeaderError, image_size
    from pal.io.sequence_files import read_image

    image = np.zeros((30, 50, 3), np.uint8)
    for ext in (".png", ".jpg", ".bmp", ".ppm", ".tif"):
        assert cv2.imwrite(str(tmp_path / f"a{ext}"), image)
        assert image_size(tmp_path / f"a{ext}") == (50, 30), ext
        assert read_image(tmp_path / f"a{ext}").shape == (30, 50, 3)
    assert cv2.imwrite(str(tmp_path / "d.pgm"), np.ones((30, 50), np.uint16))
    assert image_size(tmp_path / "d.pgm") == (50, 30)
    with pytest.raises(SequenceError, match=r"a\.png is 50x30 = 1500 pixels, more than the 1000 allowed"):
        read_image(tmp_path / "a.png", max_pixels=1000)
    (tmp_path / "x.gif").write_bytes(b"GIF89a" + bytes(20))
    with pytest.raises(SequenceError, match=r"x\.gif starts with b'GIF89a.*not a PNG, JPEG"):
        read_image(tmp_path / "x.gif")
    (tmp_path / "t.png").write_bytes((tmp_path / "a.png").read_bytes()[:20])
    with pytest.raises(ImageHeaderError, match=r"t\.png: the image header is truncated"):
        image_size(tmp_path / "t.png")


def _pal_sequence(tmp_path):
    from pal.perception.sequence import SequenceWriter

    with SequenceWriter(tmp_path / "s", label_names={1: "box"}) as w:
        w.append(RGBDFrame(np.zeros((8, 8, 3), np.uint8), np.ones((8, 8), np.float32), np.array(DESK_K), 0.0))
    return tmp_path / "s"


@pytest.mark.parametrize(
    ("key", "value", "match"),
    [
        ("depth_scale", [1], r"'depth_scale' is \[1\], expected a number > 0"),
        ("depth_scale", "0.001", r"'depth_scale' is '0.001', expected a number > 0"),
        ("width", 8.5, r"'width' is 8\.5, expected an int >= 1"),
        ("num_frames", True, r"'num_frames' is True, expected an int >= 1"),
        ("height", None, r"'height' is None, expected an int >= 1"),
        ("metadata", [1, 2], r"'metadata' is \[1, 2\], expected a JSON object"),
        ("label_names", ["box"], r"'label_names' is \['box'\], expected an object"),
        (
            "label_names",
            {"one": "box"},
            r"'label_names' is \{'one': 'box'\}, expected an object of integer id",
        ),
        ("gt_objects", 3, r"'gt_objects' is 3, expected a list of object names"),
        ("gt_objects", [1], r"'gt_objects' is \[1\], expected a list of object names"),
        ("has_masks", "yes", r"'has_masks' is 'yes', expected true or false"),
    ],
)
def test_malformed_pal_sequence_metadata_is_refused_naming_file_key_and_value(tmp_path, key, value, match):
    s = _pal_sequence(tmp_path)
    info = json.loads((s / "sequence.json").read_text())
    (s / "sequence.json").write_text(json.dumps({**info, key: value}))
    with pytest.raises(SequenceError, match=r"sequence\.json: " + match):
        open_sequence(s)


@pytest.mark.parametrize(
    ("content", "match"),
    [
        ({"K": "abc"}, r"intrinsics\.json: K is 'abc', expected a \(3, 3\) list"),
        ({"K": {"fx": 1}}, r"intrinsics\.json: K is \{'fx': 1\}, expected a \(3, 3\) list"),
        ({"K": [["a", "b", "c"], [0, 1, 0], [0, 0, 1]]}, r"intrinsics\.json: could not convert string"),
        (
            {"K": [[1, 0], [0, 1, 0], [0, 0, 1]]},
            r"intrinsics\.json: .*inhomogeneous|intrinsics\.json: .*sequence",
        ),
        ([1, 2], r"intrinsics\.json holds list, expected a JSON object"),
    ],
)
def test_malformed_intrinsics_are_refused_naming_the_file(tmp_path, content, match):
    s = _pal_sequence(tmp_path)
    (s / "intrinsics.json").write_text(json.dumps(content))
    with pytest.raises(SequenceError, match=match):
        open_sequence(s)


def test_malformed_timestamps_and_ground_truth_are_refused_naming_the_file(tmp_path):
    s = _pal_sequence(tmp_path)
    (s / "timestamps.txt").write_text("0 abc\n")
    with pytest.raises(SequenceError, match=r"timestamps\.txt: a timestamp is not a number"):
        open_sequence(s)
    (s / "timestamps.txt").write_text("0 nan\n")
    with pytest.raises(SequenceError, match=r"timestamps\.txt: timestamp nan of frame 0 is not finite"):
        open_sequence(s)
    (s / "timestamps.txt").write_bytes(b"0 \xff\n")
    with pytest.raises(SequenceError, match=r"timestamps\.txt is not a readable text file"):
        open_sequence(s)


def test_malformed_tum_ground_truth_is_refused_naming_the_file(tmp_path):
    d = _tum(tmp_path, "1.0 a.png\n")
    seq = open_sequence(d, K=np.array(DESK_K), depth_scale=0.001)
    (d / "groundtruth.txt").write_text("1.0 1 2 3 0 0 0 one\n")
    with pytest.raises(SequenceError, match=r"groundtruth\.txt: expected rows of 8 numbers"):
        seq.groundtruth()
    (d / "groundtruth.txt").write_text("1.0 1 2 3\n")
    with pytest.raises(SequenceError, match=r"groundtruth\.txt: expected rows"):
        seq.camera_poses()


_JSON_VALUES = [None, True, 0, -1, 1.5, float("1e308"), "s", "", [], [1], [[1, 2]], {}, {"1": 2}]


@pytest.mark.filterwarnings("ignore::pal.frames.DepthUnitsWarning", "ignore::RuntimeWarning")
def test_every_json_type_in_every_key_gives_a_sequence_error_or_a_sequence(tmp_path):
    s = _pal_sequence(tmp_path)
    files = {
        "sequence.json": json.loads((s / "sequence.json").read_text()),
        "intrinsics.json": json.loads((s / "intrinsics.json").read_text()),
    }
    for name, original in files.items():
        for key in original:
            for value in _JSON_VALUES:
                (s / name).write_text(json.dumps({**original, key: value}))
                try:
                    seq = open_sequence(s)
                    seq[0]
                except SequenceError as err:
                    assert str(s / name) in str(err) or str(s) in str(err), (name, key, value, err)
            (s / name).write_text(json.dumps(original))
    tum = _tum(tmp_path, "1.0 a.png\n")
    for key in ("fx", "fy", "cx", "cy", "depth_scale", "fps", "K"):
        for value in _JSON_VALUES:
            calib = {"fx": 500, "fy": 500, "cx": 4, "cy": 4, "depth_scale": 0.001, key: value}
            (tum / "calibration.json").write_text(json.dumps(calib))
            try:
                open_sequence(tum)[0]
            except SequenceError as err:
                assert str(tum) in str(err), (key, value, err)


def test_folder_and_pal_sequences_refuse_files_linked_from_outside(tmp_path):
    outside = tmp_path / "outside.png"
    cv2.imwrite(str(outside), np.zeros((8, 8, 3), np.uint8))
    d = tmp_path / "folder"
    d.mkdir()
    cv2.imwrite(str(d / "1_depth.png"), np.full((8, 8), 1000, np.uint16))
    (d / "1.png").symlink_to(outside)
    with pytest.raises(
        SequenceError, match=r"folder: the file '.*1\.png' resolves to .*outside\.png, outside"
    ):
        open_sequence(d, K=np.array(DESK_K), depth_scale=0.001, fps=1.0)
    s = _pal_sequence(tmp_path)
    (s / "rgb" / "000000.png").unlink()
    (s / "rgb" / "000000.png").symlink_to(outside)
    with pytest.raises(
        SequenceError, match=r"the file 'rgb/000000\.png' resolves to .*outside the sequence folder"
    ):
        open_sequence(s)[0]
