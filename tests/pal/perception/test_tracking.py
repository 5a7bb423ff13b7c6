"""Association to memory (Eq. 4.9-4.11): stable ids, IoM, optimal assignment, re-identification."""

from __future__ import annotations

import numpy as np
import pytest

from pal.perception.masks import Mask
from pal.perception.segmentation import Candidate
from pal.perception.tracking import Tracker, TrackerConfig, overlap_matrices

SHAPE = (60, 120)


def rect(x0: int, x1: int, y0: int = 10, y1: int = 30, label: int = 0) -> Candidate:
    crop_h, crop_w = y1 - y0, x1 - x0
    return Candidate(Mask((x0, y0, x1, y1), np.ones((crop_h, crop_w), bool), SHAPE, crop_h * crop_w), label)


def test_ids_stay_stable_while_objects_move():
    tr = Tracker()
    ids = None
    for k in range(20):
        obs = tr.update([rect(5 + k, 25 + k), rect(60 - k, 80 - k, 35, 55)], 0.1 * k)
        now = [o.track_id for o in obs]
        assert ids is None or now == ids
        ids = now
        assert all(o.status == ("born" if k == 0 else "tracked") for o in obs)
    assert ids == [1, 2]


def test_iom_associates_a_partial_mask():
    tr = Tracker(TrackerConfig(tau_iou=0.5, tau_iom=0.9))
    tr.update([rect(10, 50)], 0.0)
    half = rect(10, 24)  # IoU 14/40 = 0.35 < 0.5, IoM 1.0
    obs = tr.update([half], 0.1)
    assert obs[0].track_id == 1 and obs[0].iou == pytest.approx(0.35) and obs[0].iom == pytest.approx(1.0)
    other = Tracker()
    other.update([rect(10, 50)], 0.0)
    obs = other.update([rect(40, 60)], 0.1)  # IoU 10/50 = 0.2, IoM 10/20 = 0.5: incompatible
    assert obs[0].status == "born" and obs[0].track_id == 2


def test_assignment_is_optimal_not_greedy():
    # tracks A = [0, 20), B = [0, 60); candidates X = [0, 40), Y = [20, 80).
    # Greedy takes the best pair X-B (IoU 0.67) and leaves Y unmatched; the optimal one-to-one
    # assignment X-A (0.5) + Y-B (0.5) explains both candidates.
    iou, _ = overlap_matrices([rect(0, 40).mask, rect(20, 80).mask], [rect(0, 20).mask, rect(0, 60).mask])
    assert iou[0, 1] > max(iou[0, 0], iou[1, 1]) and iou[0, 0] + iou[1, 1] > iou[0, 1] and iou[1, 0] == 0
    tr = Tracker()
    a, b = (o.track_id for o in tr.update([rect(0, 20), rect(0, 60, 10, 30)], 0.0))
    obs = tr.update([rect(0, 40), rect(20, 80)], 0.1)
    assert [o.track_id for o in obs] == [a, b]
    assert all(o.status == "tracked" for o in obs)


def test_reidentification_within_the_window_and_death_after_it():
    tr = Tracker(TrackerConfig(reid_window_s=2.0))
    first = tr.update([rect(10, 30), rect(70, 90)], 0.0)
    for k in range(1, 11):  # the second object is occluded for 1 s
        tr.update([rect(10, 30)], 0.1 * k)
    back = tr.update([rect(10, 30), rect(71, 91)], 1.1)
    assert back[1].track_id == first[1].track_id and back[1].status == "reidentified"
    for k in range(12, 45):  # now it stays away for 3.3 s
        tr.update([rect(10, 30)], 0.1 * k)
    assert first[1].track_id in tr.dead and first[1].track_id not in tr.tracks
    late = tr.update([rect(10, 30), rect(70, 90)], 4.5)
    assert late[1].status == "born" and late[1].track_id == 3  # ids are never reused


def test_trusted_labels_follow_a_teleporting_object():
    tr = Tracker(TrackerConfig(trust_labels=True))
    tr.update([rect(0, 10, label=7)], 0.0)
    obs = tr.update([rect(100, 110, label=7)], 0.1)
    assert obs[0].track_id == 1 and obs[0].status == "tracked"
    assert Tracker().update([rect(0, 10, label=7)], 0.0)[0].track_id == 1


def test_time_must_not_go_backwards_and_config_is_checked():
    tr = Tracker()
    tr.update([], 1.0)
    with pytest.raises(ValueError, match="earlier than the previous"):
        tr.update([], 0.5)
    with pytest.raises(ValueError, match="tau_iou"):
        TrackerConfig(tau_iou=0.0)
    with pytest.raises(ValueError, match="reid_window_s"):
        TrackerConfig(reid_window_s=-1.0)


def test_constant_velocity_prediction_keeps_a_fast_object():
    """A 20 px mask accelerating to 12 px per update (IoU 0.25 with its last mask) keeps its id."""
    x = [5, 9, 17, 29, 41, 53, 65]  # steps 4, 8, 12, 12, ... px
    fast = [rect(x0, x0 + 20) for x0 in x]
    tr = Tracker()
    assert {tr.update([c], 0.1 * k)[0].track_id for k, c in enumerate(fast)} == {1}
    still = Tracker(TrackerConfig(predict_s=0.0))  # without prediction: a new id from the 8 px step on
    assert len({still.update([c], 0.1 * k)[0].track_id for k, c in enumerate(fast)}) == len(fast) - 1
    with pytest.raises(ValueError, match="predict_s"):
        TrackerConfig(predict_s=-1.0)
