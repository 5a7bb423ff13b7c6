"""A static object's pose from the camera's egomotion, checked against the live depth and grey levels.

For an object presumed static (not moving, estimated within ``checks.static_horizon_s``) and a
camera whose motion was measured, that motion predicts its pose::

    camera_from_object(t) = inverse(world_from_camera(t)) · world_from_object(t_last)

:func:`predicted_pose` scores that prediction, without a step, with the terms of the dense fit
(:func:`pal.perception.icp.icp_score`: the surface and grey levels of the snapshot closest in
view, projected where the prediction puts them). The prediction is taken as this frame's
``estimated`` pose (solver ``egomotion``) — and the feature fit and the dense fit are skipped —
only when the data would have seen a deviation and sees none:

- the checks of the dense fit (:func:`pal.perception.pose_dense.dense_checks`: enough agreeing
  points, few in free space, residual at the sensor's noise, a surface that pins all six
  degrees of freedom, a precise covariance);
- agreement and residual bounds of its own (``min_agreement``, ``max_rmse_sigma``);
- a grey-level residual at the image noise (``max_photometric_sigma``: the robust spread of the
  photometric residuals, in units of the dense fit's ``photometric_sigma``): texture shows the
  slides that depth cannot.

:func:`predicted_poses` checks the predictions of all of a frame's objects at once
(:func:`pal.perception.icp_batch.icp_scores`), with the same result as one at a time.

An object whose fits keep failing is fitted only every few frames (:func:`fit_due`,
``PoseConfig.retry``).

Every ``refit_every``-th frame in a row the object is fitted again by features (and the dense
fallback), so a drift of the camera's motion cannot go on unmeasured. The pose carries the
covariance of the check's terms at the prediction; its world-frame pose does not move.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from pal.perception.icp import IcpFit, icp_score
from pal.perception.icp_batch import ScoreItem, icp_scores
from pal.perception.pose_dense import dense_checks, snapshot_surface
from pal.perception.pose_matching import choose_snapshots
from pal.perception.trajectory import Pose, PoseDiagnostics

if TYPE_CHECKING:
    from pal.perception.frames import RGBDFrame
    from pal.perception.masks import Mask
    from pal.perception.memory import ObjectRecord, Snapshot
    from pal.perception.pose_config import FitRetry, PoseConfig

__all__ = ["fit_due", "predicted_pose", "predicted_poses"]


def _eligible(record: ObjectRecord, t: float, config: PoseConfig, camera_known: bool) -> bool:
    check = config.prediction
    if check is None or config.icp is None or not camera_known or record.moving:
        return False
    if record.world_pose is None or record.gallery.canonical is None:
        return False
    if t - record.world_pose[0] > config.checks.static_horizon_s:
        return False
    return record.predicted_run < check.refit_every - 1


def _prepare(
    record: ObjectRecord, t: float, mask: Mask, W: np.ndarray, config: PoseConfig, camera_known: bool
) -> tuple[np.ndarray, Snapshot, ScoreItem | None] | None:
    """(prior, snapshot, the item to score or None without model points), or None: nothing to check."""
    if not _eligible(record, t, config, camera_known):
        record.predicted_run = 0
        return None
    assert config.icp is not None and record.world_pose is not None
    if W.shape != (4, 4):
        raise ValueError(f"world_from_camera has shape {W.shape}; expected (4, 4)")
    prior = np.linalg.inv(W) @ record.world_pose[1]
    snaps = choose_snapshots(record, 1, prior)
    if not snaps or snaps[0].anchor is None:
        record.predicted_run = 0
        return None
    model, values, step = snapshot_surface(snaps[0], config.icp, (config.min_depth, config.max_depth))
    return prior, snaps[0], ScoreItem(model, prior, mask, values, step) if len(model) else None


def _confirm(
    record: ObjectRecord,
    fit: IcpFit | None,
    prior: np.ndarray,
    snap: Snapshot,
    W: np.ndarray,
    t: float,
    config: PoseConfig,
) -> Pose | None:
    """The prediction ``prior`` as the pose when its score ``fit`` passes every check, else None."""
    check = config.prediction
    assert check is not None
    if (
        fit is None
        or dense_checks(fit, record, prior, W, t, config)
        or fit.agreement < check.min_agreement
        or fit.rmse_sigma > check.max_rmse_sigma
        or (fit.photometric > 0 and fit.photometric_sigma > check.max_photometric_sigma)
    ):
        record.predicted_run = 0
        return None
    record.predicted_run += 1
    record.world_pose = (t, record.world_pose[1])  # type: ignore[index]
    record.speed = 0.0
    diag = PoseDiagnostics(
        0,
        fit.visible,
        fit.points,
        fit.rmse,
        "egomotion",
        f"egomotion prediction confirmed by depth and grey levels ({fit.agreement:.0%} agree)",
        snap.index,
        1,
        fit.agreement,
    )
    return Pose(t, "estimated", prior.copy(), diag, fit.covariance)


def predicted_pose(
    record: ObjectRecord,
    frame: RGBDFrame,
    mask: Mask,
    world_from_camera: np.ndarray,
    config: PoseConfig,
    camera_known: bool,
) -> Pose | None:
    """The checked egomotion prediction of ``record``'s pose in ``frame``, or None (module docstring).

    Args:
        record: the object's record; on success its world pose is re-stamped at the frame's
            time (same pose) and its run of predicted poses counted.
        frame: the live frame.
        mask: the object's live mask.
        world_from_camera: (4, 4) the live camera's pose in the world, metres.
        config: the pose estimator's parameters (``config.prediction`` and ``config.icp`` set).
        camera_known: the camera's motion into this frame was measured.

    Returns:
        An ``estimated`` pose with solver ``egomotion``, or None: not eligible or not confirmed
        (then the caller fits the pose; the run of predicted poses restarts).

    Raises:
        ValueError: ``world_from_camera`` is not (4, 4).
    """
    t, W = frame.timestamp, np.asarray(world_from_camera, dtype=np.float64)
    prepared = _prepare(record, t, mask, W, config, camera_known)
    if prepared is None:
        return None
    prior, snap, item = prepared
    fit = None
    if item is not None:
        fit = icp_score(item.model, prior, frame, mask, config.noise, config.icp, item.model_gray, item.step)
    return _confirm(record, fit, prior, snap, W, t, config)


def predicted_poses(
    objects: Sequence[tuple[ObjectRecord, Mask]],
    frame: RGBDFrame,
    world_from_camera: np.ndarray,
    config: PoseConfig,
    camera_known: bool,
) -> list[Pose | None]:
    """:func:`predicted_pose` of several objects, their predictions scored in one pass.

    The same as ``[predicted_pose(r, frame, m, ...) for r, m in objects]`` (each record is
    updated as there), with the scores of :func:`pal.perception.icp_batch.icp_scores`.

    Args:
        objects: (record, live mask) of each object; every record at most once.
        frame: the live frame.
        world_from_camera: (4, 4) the live camera's pose in the world, metres.
        config: the pose estimator's parameters.
        camera_known: the camera's motion into this frame was measured.

    Returns:
        Per object, its ``egomotion`` pose or None.

    Raises:
        ValueError: ``world_from_camera`` is not (4, 4), or a record appears twice.
    """
    t, W = frame.timestamp, np.asarray(world_from_camera, dtype=np.float64)
    if len({id(r) for r, _ in objects}) != len(objects):
        raise ValueError("objects name a record more than once; each object is predicted once per frame")
    prepared = [_prepare(r, t, m, W, config, camera_known) for r, m in objects]
    items = [p[2] for p in prepared if p is not None and p[2] is not None]
    fits = iter(icp_scores(items, frame, config.noise, config.icp))
    out: list[Pose | None] = []
    for (record, _), p in zip(objects, prepared, strict=True):
        if p is None:
            out.append(None)
            continue
        fit = next(fits) if p[2] is not None else None
        out.append(_confirm(record, fit, p[0], p[1], W, t, config))
    return out


def fit_due(record: ObjectRecord, retry: FitRetry | None) -> bool:
    """Whether ``record``'s object is fitted in this frame (its prediction was not taken).

    Always, unless the object has a canonical frame and its last ``retry.after`` or more fits
    failed in a row (``record.failed_fits``, which the caller counts, skipped frames included);
    then on every ``retry.every``-th frame: after ``after`` failures, the frames
    ``after + every - 1``, ``after + 2 every - 1``, ... of the run. An object without a
    canonical frame is tried in every frame (the frame is defined by its first good view).
    """
    if retry is None or record.failed_fits < retry.after or record.gallery.canonical is None:
        return True
    return (record.failed_fits - retry.after) % retry.every == retry.every - 1
