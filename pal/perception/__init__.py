"""pal.perception: the perceptual subsystem Π of thesis §4.2, from RGB-D frames to ŝ_vis(t).

Stages (one module each): :mod:`~pal.perception.frames` (re-exports the frame contract
``RGBDFrame`` of :mod:`pal.frames`),
:mod:`~pal.perception.sequence` / :mod:`~pal.perception.tum` / :mod:`~pal.perception.folders`
(recordings; :mod:`~pal.perception.calibration` for their camera, :mod:`~pal.perception.samples`
for the real frames shipped with pal), :mod:`~pal.perception.noise` (the sensor's noise model),
:mod:`~pal.perception.plane` / :mod:`~pal.perception.support` (the support plane),
:mod:`~pal.perception.segmentation` (Σ, Eq. 4.8; :mod:`~pal.perception.regions`,
:mod:`~pal.perception.creases`),
:mod:`~pal.perception.egomotion` (the camera's motion, :mod:`~pal.perception.pnp`),
:mod:`~pal.perception.tracking` (Eq. 4.9-4.11; :mod:`~pal.perception.association`), :mod:`~pal.perception.memory` (EEMS, Eq. 4.12-4.13),
:mod:`~pal.perception.pose` (Eq. 4.14-4.17; :mod:`~pal.perception.pose_config`, :mod:`~pal.perception.pose_matching`, :mod:`~pal.perception.pose_checks`, :mod:`~pal.perception.icp`, :mod:`~pal.perception.pose_dense`), :mod:`~pal.perception.trajectory` (Eq. 4.18),
:mod:`~pal.perception.filters` (1€), :mod:`~pal.perception.kinematic` and
:mod:`~pal.perception.visual` (descriptors), :mod:`~pal.perception.normalise`,
:mod:`~pal.perception.concepts` (Eq. 1.3-1.7, 4.23-4.26), :mod:`~pal.perception.spatial`,
:mod:`~pal.perception.relations` (Eq. 4.21-4.22; :mod:`~pal.perception.topology`,
:mod:`~pal.perception.grounding`), :mod:`~pal.perception.scene` (Table 5.6) and
:mod:`~pal.perception.pipeline` (Π, Eq. 4.5). :mod:`~pal.perception.synthetic` renders
analytic RGB-D scenes with exact ground truth.

This package consumes frames; it imports neither ``models``, ``inference`` nor ``pal.sim``.
"""

from pal.perception.calibration import Calibration
from pal.perception.concepts import Categorization, ConceptualSpace, Domain, Entity
from pal.perception.egomotion import CameraMotion, EgoMotion, EgoMotionConfig
from pal.perception.filters import OneEuroConfig, OneEuroFilter, one_euro
from pal.perception.folders import FolderSequence
from pal.perception.fragments import FragmentMerger, MergeConfig
from pal.perception.frames import RGBDFrame, backproject, check_intrinsics, crop_intrinsics, project
from pal.perception.grounding import PREDICATES, GroundingConfig
from pal.perception.icp import IcpConfig
from pal.perception.kinematic import (
    KINEMATIC_DIM,
    KinematicConfig,
    KinematicDescriptor,
    kinematic_descriptor,
    trajectory_descriptor,
)
from pal.perception.masks import Mask, iom, iou
from pal.perception.memory import AdmissionConfig, AdmissionDecision, Gallery, ObjectRecord, Snapshot
from pal.perception.noise import DepthNoise
from pal.perception.normalise import NotFittedError, RobustNormaliser
from pal.perception.pipeline import ObjectState, PerceptionState, Pipeline, PipelineConfig
from pal.perception.pose import PoseConfig, PoseEstimator
from pal.perception.pose_checks import PoseChecks
from pal.perception.reid import ReidConfig
from pal.perception.relations import TOPOLOGY, PairRelation, RelationConfig, SceneRelations, scene_relations
from pal.perception.samples import SAMPLES, open_sample
from pal.perception.scene import OBJECT_KEYS, SCENE_KEYS, scene_descriptor
from pal.perception.segmentation import Candidate, GeometricSegmenter, OracleSegmenter, SegmentationConfig
from pal.perception.sequence import (
    FrameSequence,
    RecordedSequence,
    SequenceError,
    SequenceWriter,
    open_sequence,
)
from pal.perception.spatial import SpatialDescriptor, spatial_descriptor
from pal.perception.support import SupportConfig
from pal.perception.topology import TopologyConfig
from pal.perception.tracking import Observation, Tracker, TrackerConfig
from pal.perception.trajectory import Pose, PoseDiagnostics, Trajectory
from pal.perception.tum import TUMSequence
from pal.perception.visual import VISUAL_DIM, VISUAL_FAMILIES, VISUAL_HISTOGRAMS, visual_descriptor

__all__ = [
    "KINEMATIC_DIM",
    "OBJECT_KEYS",
    "PREDICATES",
    "SAMPLES",
    "SCENE_KEYS",
    "TOPOLOGY",
    "VISUAL_DIM",
    "VISUAL_FAMILIES",
    "VISUAL_HISTOGRAMS",
    "AdmissionConfig",
    "AdmissionDecision",
    "Calibration",
    "CameraMotion",
    "Candidate",
    "Categorization",
    "ConceptualSpace",
    "DepthNoise",
    "Domain",
    "EgoMotion",
    "EgoMotionConfig",
    "Entity",
    "FolderSequence",
    "FragmentMerger",
    "FrameSequence",
    "Gallery",
    "GeometricSegmenter",
    "GroundingConfig",
    "IcpConfig",
    "KinematicConfig",
    "KinematicDescriptor",
    "Mask",
    "MergeConfig",
    "NotFittedError",
    "ObjectRecord",
    "ObjectState",
    "Observation",
    "OneEuroConfig",
    "OneEuroFilter",
    "OracleSegmenter",
    "PairRelation",
    "PerceptionState",
    "Pipeline",
    "PipelineConfig",
    "Pose",
    "PoseChecks",
    "PoseConfig",
    "PoseDiagnostics",
    "PoseEstimator",
    "RGBDFrame",
    "RecordedSequence",
    "ReidConfig",
    "RelationConfig",
    "RobustNormaliser",
    "SceneRelations",
    "SegmentationConfig",
    "SequenceError",
    "SequenceWriter",
    "Snapshot",
    "SpatialDescriptor",
    "SupportConfig",
    "TUMSequence",
    "TopologyConfig",
    "Tracker",
    "TrackerConfig",
    "Trajectory",
    "backproject",
    "check_intrinsics",
    "crop_intrinsics",
    "iom",
    "iou",
    "kinematic_descriptor",
    "one_euro",
    "open_sample",
    "open_sequence",
    "project",
    "scene_descriptor",
    "scene_relations",
    "spatial_descriptor",
    "trajectory_descriptor",
    "visual_descriptor",
]
