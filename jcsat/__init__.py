"""JCSAT (Jiang et al., TVCG 2025) pipeline pieces: the Joint Cloud, its person clustering, and a geometric baseline."""

from ._joint_cloud import JointCloud as JointCloud
from ._joint_cloud import JointCloudConfig as JointCloudConfig
from ._joint_cloud import build_joint_cloud as build_joint_cloud
from ._joint_cloud import joint_cloud_frame as joint_cloud_frame
from ._joint_cloud import triangulate_candidate_pair as triangulate_candidate_pair
from ._joint_cloud import view_pairs as view_pairs
