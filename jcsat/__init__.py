"""JCSAT (Jiang et al., TVCG 2025) pipeline pieces: the Joint Cloud (paper Sec. 3.1), its person
clustering and tracking (Algorithm 1), the padded model tensor, and a learning-free geometric baseline.

Each private module defines ``__all__``; the public names are re-exported here explicitly.
"""

from ._clustering import BODY25_JOINT_RADIUS as BODY25_JOINT_RADIUS
from ._clustering import ClusterConfig as ClusterConfig
from ._clustering import FrameClusters as FrameClusters
from ._clustering import KMeansResult as KMeansResult
from ._clustering import PersonJointCloud as PersonJointCloud
from ._clustering import cluster_frames as cluster_frames
from ._clustering import kmeans as kmeans
from ._clustering import people_count as people_count
from ._clustering import person_joint_cloud as person_joint_cloud
from ._clustering import track_centres as track_centres
from ._clustering import window_frames as window_frames
from ._experiment import METHODS as METHODS
from ._experiment import ShelfExperimentConfig as ShelfExperimentConfig
from ._experiment import ShelfExperimentResult as ShelfExperimentResult
from ._experiment import run_shelf_experiment as run_shelf_experiment
from ._experiment import synthetic_validation as synthetic_validation
from ._geometric import GeometricConfig as GeometricConfig
from ._geometric import GeometricPoses as GeometricPoses
from ._geometric import consensus_joint as consensus_joint
from ._geometric import fill_missing as fill_missing
from ._geometric import geometric_poses as geometric_poses
from ._geometric import reject_temporal_outliers as reject_temporal_outliers
from ._joint_cloud import JointCloud as JointCloud
from ._joint_cloud import JointCloudConfig as JointCloudConfig
from ._joint_cloud import build_joint_cloud as build_joint_cloud
from ._joint_cloud import joint_cloud_frame as joint_cloud_frame
from ._joint_cloud import triangulate_candidate_pair as triangulate_candidate_pair
from ._joint_cloud import view_pairs as view_pairs
from ._numpy_reference import numpy_joint_cloud_frame as numpy_joint_cloud_frame
from ._pipeline import BaselineConfig as BaselineConfig
from ._pipeline import BaselineResult as BaselineResult
from ._pipeline import run_geometric_baseline as run_geometric_baseline

__all__ = [
    "BODY25_JOINT_RADIUS", "BaselineConfig", "BaselineResult", "ClusterConfig", "FrameClusters",
    "GeometricConfig", "GeometricPoses", "METHODS", "ShelfExperimentConfig", "ShelfExperimentResult", "JointCloud", "JointCloudConfig", "KMeansResult", "PersonJointCloud",
    "build_joint_cloud", "cluster_frames", "consensus_joint", "fill_missing", "geometric_poses", "joint_cloud_frame",
    "kmeans", "numpy_joint_cloud_frame", "people_count", "person_joint_cloud", "reject_temporal_outliers", "run_geometric_baseline", "run_shelf_experiment", "synthetic_validation", "track_centres",
    "triangulate_candidate_pair", "view_pairs", "window_frames",
]
