"""The shared geometry core: cameras, projection, triangulation, rotations, skeletons, kinematics, body model,
body capsules (signed distance and interpenetration), metrics.

Every public function is pure and written for one item (one point, one camera, one pose), with
shapes and units in its jaxtyping signature; batch with ``jax.vmap`` and compile with ``jax.jit``.
Each private module lists its public names in ``__all__``; they are re-exported here.

Importing ``geometry`` changes no global state; it refuses jaxlib 0.10.2, which miscompiles our kernels on CPU,
unless its faulty fusion pass is off. Entry points and notebooks call :func:`disable_faulty_cpu_fusion` before
jax computes anything (see ``geometry/_jax_guard.py``).
"""

from importlib.metadata import version as _version

from ._body import BodyModel as BodyModel
from ._body import BodyOutput as BodyOutput
from ._body import body_forward as body_forward
from ._body import body_joints as body_joints
from ._body import body_points as body_points
from ._body import load_body_model as load_body_model
from ._body import stand_in_body_model as stand_in_body_model
from ._calibration_formats import CALIBRATION_FORMATS as CALIBRATION_FORMATS
from ._calibration_formats import Calibration as Calibration
from ._calibration_formats import load_anipose_calibration as load_anipose_calibration
from ._calibration_formats import load_calibration as load_calibration
from ._calibration_formats import load_easymocap_calibration as load_easymocap_calibration
from ._calibration_formats import save_anipose_calibration as save_anipose_calibration
from ._calibration_formats import save_calibration as save_calibration
from ._calibration_formats import save_easymocap_calibration as save_easymocap_calibration
from ._calibration_io import CAMPUS_IMAGE_SIZE as CAMPUS_IMAGE_SIZE
from ._calibration_io import CalibrationError as CalibrationError
from ._calibration_io import SHELF_IMAGE_SIZE as SHELF_IMAGE_SIZE
from ._calibration_io import load_4dassociation_calibration as load_4dassociation_calibration
from ._calibration_io import load_projection_matrices as load_projection_matrices
from ._calibration_io import load_voxelpose_calibration as load_voxelpose_calibration
from ._calibration_io import save_4dassociation_calibration as save_4dassociation_calibration
from ._calibration_io import save_voxelpose_calibration as save_voxelpose_calibration
from ._camera import Camera as Camera
from ._camera import camera_centre as camera_centre
from ._camera import camera_from_projection as camera_from_projection
from ._camera import crop_camera_to_translation as crop_camera_to_translation
from ._camera import depth as depth
from ._camera import look_at as look_at
from ._camera import point_depth as point_depth
from ._camera import project as project
from ._camera import project_pinhole as project_pinhole
from ._camera import project_point as project_point
from ._camera import project_to_views as project_to_views
from ._camera import projection_matrix as projection_matrix
from ._camera import to_camera_frame as to_camera_frame
from ._camera import translation_to_crop_camera as translation_to_crop_camera
from ._camera import undistort_points as undistort_points
from ._capsules import Capsules as Capsules
from ._capsules import body_capsules as body_capsules
from ._capsules import capsule_sdf as capsule_sdf
from ._capsules import penetration as penetration
from ._capsules import surface_points as surface_points
from ._convert import HEAD_RULES as HEAD_RULES
from ._convert import HeadRule as HeadRule
from ._convert import flex20_from_structri17 as flex20_from_structri17
from ._convert import remap_joints as remap_joints
from ._convert import shelf15_conversion_matrix as shelf15_conversion_matrix
from ._convert import to_shelf15 as to_shelf15
from ._convert import to_shelf15_validity as to_shelf15_validity
from ._jax_guard import disable_faulty_cpu_fusion as disable_faulty_cpu_fusion
from ._files import replace_file as replace_file
from ._kinematics import bone_lengths as bone_lengths
from ._kinematics import bone_vectors as bone_vectors
from ._kinematics import bones_to_joints_matrix as bones_to_joints_matrix
from ._kinematics import forward_kinematics as forward_kinematics
from ._kinematics import joints_from_bones as joints_from_bones
from ._kinematics import joints_to_bones_matrix as joints_to_bones_matrix
from ._metrics import JointHits as JointHits
from ._metrics import PrecisionRecall as PrecisionRecall
from ._metrics import Similarity as Similarity
from ._metrics import acceleration_error as acceleration_error
from ._metrics import aggregate_precision_recall as aggregate_precision_recall
from ._metrics import joint_precision_recall as joint_precision_recall
from ._metrics import mbls as mbls
from ._metrics import mpble as mpble
from ._metrics import mpjpe as mpjpe
from ._metrics import mpjpe_root_relative as mpjpe_root_relative
from ._metrics import pa_mpjpe as pa_mpjpe
from ._metrics import pck_2d as pck_2d
from ._metrics import pck_3d as pck_3d
from ._metrics import pcp as pcp
from ._metrics import pib as pib
from ._metrics import similarity_procrustes as similarity_procrustes
from ._rigs import perturb_extrinsics_bounded as perturb_extrinsics_bounded
from ._rigs import perturb_extrinsics_relative as perturb_extrinsics_relative
from ._rigs import ring_angles as ring_angles
from ._rigs import ring_rig as ring_rig
from ._rigs import structri_virtual_rig as structri_virtual_rig
from ._rotations import axis_angle_to_matrix as axis_angle_to_matrix
from ._rotations import axis_angle_to_quaternion as axis_angle_to_quaternion
from ._rotations import euler_to_matrix as euler_to_matrix
from ._rotations import geodesic_distance as geodesic_distance
from ._rotations import matrix_to_axis_angle as matrix_to_axis_angle
from ._rotations import matrix_to_euler as matrix_to_euler
from ._rotations import matrix_to_quaternion as matrix_to_quaternion
from ._rotations import matrix_to_rotation_6d as matrix_to_rotation_6d
from ._rotations import quaternion_conjugate as quaternion_conjugate
from ._rotations import quaternion_inverse as quaternion_inverse
from ._rotations import quaternion_multiply as quaternion_multiply
from ._rotations import quaternion_slerp as quaternion_slerp
from ._rotations import quaternion_to_axis_angle as quaternion_to_axis_angle
from ._rotations import quaternion_to_matrix as quaternion_to_matrix
from ._rotations import relative_rotation as relative_rotation
from ._rotations import rotation_6d_to_matrix as rotation_6d_to_matrix
from ._rotations import rotation_angle as rotation_angle
from ._rotations import rotation_between as rotation_between
from ._skeleton import BODY25 as BODY25
from ._skeleton import COCO17 as COCO17
from ._skeleton import FLEX20 as FLEX20
from ._skeleton import FLEX20_BONES as FLEX20_BONES
from ._skeleton import FLEX20_BONE_OF_JOINT as FLEX20_BONE_OF_JOINT
from ._skeleton import FLEX20_DUPLICATE_OF as FLEX20_DUPLICATE_OF
from ._skeleton import FLEX20_END_EFFECTORS as FLEX20_END_EFFECTORS
from ._skeleton import FLEX20_REST_DIRECTIONS as FLEX20_REST_DIRECTIONS
from ._skeleton import FLEX20_ROTATING as FLEX20_ROTATING
from ._skeleton import SHELF14 as SHELF14
from ._skeleton import SHELF15 as SHELF15
from ._skeleton import SKEL19 as SKEL19
from ._skeleton import SKELETONS as SKELETONS
from ._skeleton import SMPL24 as SMPL24
from ._skeleton import STRUCTRI17 as STRUCTRI17
from ._skeleton import Skeleton as Skeleton
from ._triangulate import Triangulation as Triangulation
from ._triangulate import triangulate as triangulate
from ._triangulate import triangulate_pixels as triangulate_pixels
from ._triangulate import triangulate_point as triangulate_point
from ._vectors import safe_norm as safe_norm

__version__ = _version("mvmocap")
