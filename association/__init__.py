"""Learning-free multi-person association: from multi-view 2D detections to people, tracks and 3D poses.

Used by JCSAT (its input tensor), the geometric baseline and anything else that needs people and tracks from
calibrated multi-view 2D keypoints. The stages, in order:

1. **Joint Cloud** (JCSAT paper Sec. 3.1, :func:`build_joint_cloud`): every same-type pair of 2D detections of
   every view pair, triangulated and filtered by score, ray distance and cheirality.
2. **K-Means people** (:func:`cluster_frames`): per frame, K-Means on the MidHip candidates with the number of
   people read from the detections (:func:`people_count`); each candidate joins the nearest person within its
   joint type's radius.
3. **Tracking** (:func:`track_centres`): Hungarian matching of the people's centres over frames, then
   :func:`person_joint_cloud` packs each track's candidates into the tensor the JCSAT model consumes.
   :func:`track_people` runs stages 1-3.
4. **Consensus/medoid re-triangulation** (:func:`geometric_poses`): per person, frame and joint, the weighted
   medoid of the candidates, its consensus views re-triangulated and checked by reprojection.
5. **Structural Triangulation refinement** (:func:`structural_refinement`): each track re-solved subject to its
   own bone lengths, distrusting joints whose bones are all far off (:func:`bone_outliers`).
6. **Temporal outlier filter** (:func:`reject_temporal_outliers`), then gaps filled from the nearest frame
   (:func:`fill_missing`).
7. **Ranked, de-duplicated predictions**: Shelf15 poses ranked by support, near-copies dropped.
   :func:`run_geometric_baseline` runs stages 1-7 (:class:`BaselineConfig`).

:mod:`association.numpy_reference` holds a loop implementation of the Joint Cloud in OpenCV + NumPy, the tests'
oracle and the benchmark's baseline; it is not re-exported here.
"""

from importlib.metadata import version as _version

from ._clustering import BODY25_JOINT_RADIUS as BODY25_JOINT_RADIUS
from ._clustering import cluster_frames as cluster_frames
from ._clustering import ClusterConfig as ClusterConfig
from ._clustering import FrameClusters as FrameClusters
from ._clustering import kmeans as kmeans
from ._clustering import KMeansResult as KMeansResult
from ._clustering import people_count as people_count
from ._clustering import person_joint_cloud as person_joint_cloud
from ._clustering import PersonJointCloud as PersonJointCloud
from ._clustering import track_centres as track_centres
from ._clustering import window_frames as window_frames
from ._geometric import bone_outliers as bone_outliers
from ._geometric import consensus_joint as consensus_joint
from ._geometric import ConsensusJoint as ConsensusJoint
from ._geometric import fill_missing as fill_missing
from ._geometric import filled_centres as filled_centres
from ._geometric import geometric_poses as geometric_poses
from ._geometric import GeometricConfig as GeometricConfig
from ._geometric import GeometricPoses as GeometricPoses
from ._geometric import reject_temporal_outliers as reject_temporal_outliers
from ._geometric import structural_refinement as structural_refinement
from ._geometric import track_bone_lengths as track_bone_lengths
from ._joint_cloud import build_joint_cloud as build_joint_cloud
from ._joint_cloud import joint_cloud_frame as joint_cloud_frame
from ._joint_cloud import JointCloud as JointCloud
from ._joint_cloud import JointCloudConfig as JointCloudConfig
from ._joint_cloud import triangulate_candidate_pair as triangulate_candidate_pair
from ._joint_cloud import view_pairs as view_pairs
from ._pipeline import BaselineConfig as BaselineConfig
from ._pipeline import BaselineResult as BaselineResult
from ._pipeline import PersonTracks as PersonTracks
from ._pipeline import run_geometric_baseline as run_geometric_baseline
from ._pipeline import track_people as track_people

__version__ = _version("mvmocap")
