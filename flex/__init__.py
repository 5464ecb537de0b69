"""FLEX (Gordon, Raab et al., ECCV 2022): extrinsic-free multi-view motion reconstruction.

The network (fusion layers F_Q / F_S with multi-view convolution and cross-view attention, encoders E_Q / E_S,
forward kinematics of the :data:`geometry.FLEX20` skeleton, per-joint rotation discriminator) and the averaged
monocular fusion of Table 5c, its losses (Eq. 3-9), the calibration-free input normalisation, training samples
from 3D motion seen by static or moving virtual cameras, the shipped models, the BVH export of a prediction, and
the camera-dependent triangulation baselines and metrics that FLEX is compared with. The synthetic experiment
itself lives in :mod:`experiments.flex_study`.
"""

from importlib.metadata import version as _version

from ._baselines import baseline_cameras as baseline_cameras
from ._baselines import camera_root as camera_root
from ._baselines import motion_metrics as motion_metrics
from ._baselines import root_position_error as root_position_error
from ._baselines import triangulation_baseline as triangulation_baseline
from ._baselines import MotionMetrics as MotionMetrics
from ._clips import TEST_CLIPS as TEST_CLIPS
from ._clips import TRAIN_CLIPS as TRAIN_CLIPS
from ._clips import VALIDATION_CLIPS as VALIDATION_CLIPS
from ._data import fixed_rig as fixed_rig
from ._data import local_rotations as local_rotations
from ._data import make_batch as make_batch
from ._data import make_sample as make_sample
from ._data import rig_centre as rig_centre
from ._data import root_frame as root_frame
from ._data import sign_continuous as sign_continuous
from ._data import symmetric_bone_lengths as symmetric_bone_lengths
from ._data import Batch as Batch
from ._data import DataConfig as DataConfig
from ._data import FIXED_RIGS as FIXED_RIGS
from ._detections import input_from_detections as input_from_detections
from ._detections import input_joint_weights as input_joint_weights
from ._detections import INPUT_SUPPORT as INPUT_SUPPORT
from ._export import to_bvh as to_bvh
from ._losses import adversarial_loss as adversarial_loss
from ._losses import contact_loss as contact_loss
from ._losses import contact_velocity_loss as contact_velocity_loss
from ._losses import discriminator_loss as discriminator_loss
from ._losses import generator_loss as generator_loss
from ._losses import position_loss as position_loss
from ._losses import root_loss as root_loss
from ._losses import skeleton_loss as skeleton_loss
from ._losses import LossWeights as LossWeights
from ._model import averaged_monocular as averaged_monocular
from ._model import flex_forward_kinematics as flex_forward_kinematics
from ._model import parameter_count as parameter_count
from ._model import predict as predict
from ._model import tie_duplicates as tie_duplicates
from ._model import CONFIGS as CONFIGS
from ._model import Discriminator as Discriminator
from ._model import Flex as Flex
from ._model import FlexConfig as FlexConfig
from ._model import FlexOutputs as FlexOutputs
from ._model import INDEPENDENT_ROTATIONS as INDEPENDENT_ROTATIONS
from ._model import RotationDiscriminator as RotationDiscriminator
from ._normalise import normalise_2d as normalise_2d
from ._normalise import normalise_view as normalise_view
from ._normalise import NormalisedInput as NormalisedInput
from ._shipped import DETECTION_MODELS as DETECTION_MODELS
from ._shipped import load_models as load_models
from ._shipped import MAIN_MODEL as MAIN_MODEL
from ._shipped import MODELS as MODELS
from ._shipped import RIG_MODELS as RIG_MODELS
from ._shipped import SHIPPED_MODELS as SHIPPED_MODELS
from ._shipped import SKELETON_MODELS as SKELETON_MODELS
from ._train import build_pool as build_pool
from ._train import load_flex as load_flex
from ._train import train as train
from ._train import train_step as train_step
from ._train import validation_mpjpe as validation_mpjpe
from ._train import TrainConfig as TrainConfig
from ._train import TrainState as TrainState

__version__ = _version("mvmocap")
