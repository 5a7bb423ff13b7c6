"""Recorded tabletop runs: determinism, ground truth that agrees with the images, ``pal record``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pal.cli import main
from pal.perception import RecordedSequence, open_sequence, project
from pal.sim.recording import RecordConfig, record, render_run
from pal.sim.tabletop import OBJECT_LABELS

pytestmark = pytest.mark.render

TINY = {"width": 96, "height": 72, "fps": 4.0}


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    root = tmp_path_factory.mktemp("rec")
    cfg = RecordConfig("box-translation", seed=1, **TINY)
    return cfg, record(cfg, root / "a"), record(cfg, root / "b")


def test_recording_is_deterministic_and_complete(recorded):
    _, a, b = recorded
    sa, sb = RecordedSequence(a), RecordedSequence(b)
    assert len(sa) == len(sb) > 10 and sa.has_masks and sa.gt_objects == ("ball", "boat", "box")
    assert (
        sa.metadata["motion"] == "box-translation"
        and sa.metadata["object"] == "box"
        and sa.metadata["seed"] == 1
    )
    assert sa.label_names == {v: k for k, v in OBJECT_LABELS.items()}
    for name in ("rgb", "depth", "gt/masks"):
        for fa, fb in zip(sorted((a / name).glob("*.png")), sorted((b / name).glob("*.png")), strict=True):
            assert fa.read_bytes() == fb.read_bytes(), fa
    for obj in sa.gt_objects:
        np.testing.assert_array_equal(sa.gt_poses(obj)[0], sb.gt_poses(obj)[0])
    other = list(render_run(RecordConfig("box-translation", seed=2, **TINY)))
    assert not np.array_equal(other[-1].frame.rgb, sa[len(sa) - 1].rgb)


def test_ground_truth_agrees_with_the_images(recorded):
    _, a, _ = recorded
    seq = open_sequence(a)
    poses, valid = seq.gt_poses("box")
    assert valid.all() and poses.shape == (len(seq), 4, 4)
    for k in (0, len(seq) - 1):
        f = seq[k]
        assert set(np.unique(f.labels)) == {0, 1, 2, 3}
        # the box centre projects inside the box's true mask, and depth there is near the box
        u, v = np.rint(project(poses[k, :3, 3], f.K)).astype(int)
        assert f.labels[v, u] == OBJECT_LABELS["box"]
        assert abs(f.depth[v, u] - poses[k, 2, 3]) < 0.08  # the visible surface is within the box's half-size
    moved = np.linalg.norm(poses[-1, :3, 3] - poses[0, :3, 3])
    assert moved > 0.15  # a 20-28 cm sideways slide


def test_pal_record_command(tmp_path, capsys):
    out = tmp_path / "seq"
    args = [
        "record",
        "--motion",
        "ball-roll",
        "--seed",
        "0",
        "--out",
        str(out),
        "--width",
        "64",
        "--height",
        "48",
        "--fps",
        "3",
        "--json",
    ]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["object"] == "ball" and summary["frames"] == len(open_sequence(out)) > 3
    assert main(args) == 2  # a usage error: one line on stderr
    assert "--overwrite" in capsys.readouterr().err
    assert main([*args, "--overwrite"]) == 0
    capsys.readouterr()
    assert main(["record", "--motion", "ball-bounce", "--out", str(tmp_path / "x")]) == 2
    assert "unknown motion 'ball-bounce'" in capsys.readouterr().err


def test_the_harder_tabletop_has_holes_blur_lighting_and_a_hand():
    from pal.sim.recording import Realism
    from pal.sim.tabletop import OCCLUDER_LABEL

    clean = list(render_run(RecordConfig("box-translation", seed=1, **TINY, rgb_noise=0.0)))
    hard = list(render_run(RecordConfig("box-translation", seed=1, **TINY, rgb_noise=0.0, realism=Realism())))
    assert len(hard) == len(clean)
    k = len(hard) // 2
    c, h = clean[k].frame, hard[k].frame
    assert (h.labels == OCCLUDER_LABEL).any() and not (c.labels == OCCLUDER_LABEL).any()
    valid = c.depth > 0
    assert (h.depth[valid] == 0).mean() > 0.003  # shadows, edge and random dropouts
    z = h.depth[h.depth > 0]
    step = np.diff(np.unique(1.0 / z.astype(np.float64)))
    assert step.min() > 0.5 * Realism().disparity_step  # quantised in disparity
    assert not np.array_equal(c.rgb, h.rgb)  # the hand, the blur and the lighting change the colour
    with pytest.raises(ValueError, match="dropout"):
        Realism(dropout=2.0)


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"fps": float("inf")}, "fps must be finite, got inf"),
        ({"fps": float("nan")}, "fps must be finite, got nan"),
        ({"fps": 0.0}, "fps must be > 0.0, got 0.0"),
        ({"fps": 1e6}, "fps must be <= 1000.0, got 1000000.0"),
        ({"seed": -1}, r"seed must be an int in \[0, 4294967295\], got -1"),
        ({"depth_noise": float("inf")}, "depth_noise must be finite, got inf"),
    ],
)
def test_record_config_refuses_rates_seeds_and_noise_past_the_limits(fields, message):
    with pytest.raises(ValueError, match=message):
        RecordConfig("box-rotation", **fields)
