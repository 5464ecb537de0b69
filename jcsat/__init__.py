"""JCSAT (Jiang et al., TVCG 2025): the Joint Cloud (paper Sec. 3.1), its person clustering and tracking
(Algorithm 1), the OTAP Sinkhorn aggregation and the transformer (Sec. 3.2-3.4), its losses, synthetic
training data and training loop, inference on tracks, a learning-free geometric baseline, and the
Shelf experiment behind ``python -m experiments.shelf_jcsat``.

Each private module defines ``__all__``; the public names are re-exported here explicitly.
"""

from ._clustering import cluster_frames as cluster_frames
from ._clustering import kmeans as kmeans
from ._clustering import people_count as people_count
from ._clustering import person_joint_cloud as person_joint_cloud
from ._clustering import track_centres as track_centres
from ._clustering import window_frames as window_frames
from ._clustering import BODY25_JOINT_RADIUS as BODY25_JOINT_RADIUS
from ._clustering import ClusterConfig as ClusterConfig
from ._clustering import FrameClusters as FrameClusters
from ._clustering import KMeansResult as KMeansResult
from ._clustering import PersonJointCloud as PersonJointCloud
from ._data import build_dataset as build_dataset
from ._data import sample_batch as sample_batch
from ._data import scene_windows as scene_windows
from ._data import window_batch as window_batch
from ._data import Batch as Batch
from ._data import DataConfig as DataConfig
from ._data import TRAIN_CLIPS as TRAIN_CLIPS
from ._data import VALIDATION_CLIPS as VALIDATION_CLIPS
from ._data import WindowDataset as WindowDataset
from ._geometric import consensus_joint as consensus_joint
from ._geometric import ConsensusJoint as ConsensusJoint
from ._geometric import fill_missing as fill_missing
from ._geometric import geometric_poses as geometric_poses
from ._geometric import bone_outliers as bone_outliers
from ._geometric import reject_temporal_outliers as reject_temporal_outliers
from ._geometric import structural_refinement as structural_refinement
from ._geometric import track_bone_lengths as track_bone_lengths
from ._geometric import GeometricConfig as GeometricConfig
from ._geometric import GeometricPoses as GeometricPoses
from ._inference import AGGREGATES as AGGREGATES
from ._inference import filled_centres as filled_centres
from ._inference import predict_shelf15 as predict_shelf15
from ._joint_cloud import build_joint_cloud as build_joint_cloud
from ._joint_cloud import joint_cloud_frame as joint_cloud_frame
from ._joint_cloud import triangulate_candidate_pair as triangulate_candidate_pair
from ._joint_cloud import view_pairs as view_pairs
from ._joint_cloud import JointCloud as JointCloud
from ._joint_cloud import JointCloudConfig as JointCloudConfig
from ._losses import bone_losses as bone_losses
from ._losses import jcsat_loss as jcsat_loss
from ._losses import pcp_hinge_loss as pcp_hinge_loss
from ._losses import project_normalised as project_normalised
from ._losses import projection_loss as projection_loss
from ._losses import reconstruction_loss as reconstruction_loss
from ._losses import LossConfig as LossConfig
from ._model import aggregation_variant as aggregation_variant
from ._model import parameter_count as parameter_count
from ._model import CONFIGS as CONFIGS
from ._model import JCSAT as JCSAT
from ._model import JCSATConfig as JCSATConfig
from ._numpy_reference import numpy_joint_cloud_frame as numpy_joint_cloud_frame
from ._otap import otap as otap
from ._otap import sinkhorn_plan as sinkhorn_plan
from ._otap import OTAP as OTAP
from ._pipeline import run_geometric_baseline as run_geometric_baseline
from ._pipeline import BaselineConfig as BaselineConfig
from ._pipeline import BaselineResult as BaselineResult
from ._pipeline import PersonTracks as PersonTracks
from ._pipeline import track_people as track_people
from ._shipped import SHIPPED_MODEL as SHIPPED_MODEL
from ._train import init_state as init_state
from ._train import learning_rate_schedule as learning_rate_schedule
from ._train import load_model as load_model
from ._train import make_optimizer as make_optimizer
from ._train import train as train
from ._train import TRAIN_CONFIGS as TRAIN_CONFIGS
from ._train import train_step as train_step
from ._train import TrainConfig as TrainConfig
from ._train import TrainState as TrainState

__all__ = [
    "AGGREGATES", "aggregation_variant", "BaselineConfig", "BaselineResult", "Batch", "BODY25_JOINT_RADIUS", "bone_losses",
    "build_dataset", "build_joint_cloud", "cluster_frames", "ClusterConfig", "CONFIGS", "consensus_joint",
    "ConsensusJoint",
    "bone_outliers", "DataConfig", "fill_missing", "filled_centres", "FrameClusters", "geometric_poses",
    "GeometricConfig",
    "GeometricPoses", "init_state", "JCSAT", "jcsat_loss", "JCSATConfig", "joint_cloud_frame", "JointCloud",
    "JointCloudConfig", "kmeans", "KMeansResult", "learning_rate_schedule", "load_model", "LossConfig",
    "make_optimizer", "numpy_joint_cloud_frame", "otap",
    "OTAP", "parameter_count", "pcp_hinge_loss", "people_count", "person_joint_cloud", "PersonJointCloud",
    "PersonTracks", "predict_shelf15", "project_normalised", "projection_loss", "reconstruction_loss",
    "reject_temporal_outliers", "run_geometric_baseline", "sample_batch",
    "scene_windows", "SHIPPED_MODEL", "sinkhorn_plan",
    "structural_refinement", "track_bone_lengths", "track_centres", "track_people", "train",
    "TRAIN_CLIPS", "TRAIN_CONFIGS", "train_step", "TrainConfig", "TrainState",
    "triangulate_candidate_pair", "VALIDATION_CLIPS", "view_pairs", "window_batch", "window_frames",
    "WindowDataset",
]
