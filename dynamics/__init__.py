"""Multi-person dynamics models (PHD+T and its successors, Karia 2023): their neural building blocks in Flax NNX.

- :class:`ResNetBackbone`: a small ResNet (GroupNorm, no mutable state) from person crops to features phi
  (:data:`Pooling`: its last map averaged or flattened).
- :class:`HMRHead`, :class:`SMPLParams`, :func:`mean_params`: the HMR regressor from features to SMPL pose (6D),
  shape and weak-perspective crop camera (:func:`geometry.crop_camera_to_translation` turns the camera into a
  full-perspective translation).
- :class:`CausalTCN`: PHD's temporal encoder (f_movie, f_AR), strictly causal.
- :class:`PosePrior`, :func:`lsgan_discriminator_loss`, :func:`lsgan_generator_loss`: HMR's 25 LSGAN
  discriminators on rotations and shape.
- :class:`PoseForecaster` (:data:`FORECASTERS`, :func:`train_forecasters`, :func:`load_forecasters`): the same
  models conditioned on observed 3D poses, on the CMU-Mocap benchmark's motion (:func:`pose_frames`), beside
  :func:`zero_motion_forecast` and :func:`constant_velocity_forecast` (``python -m experiments.dynamics_forecast``);
  on scenes of two people, :data:`PAIR_FORECASTERS` (JAT, MPJAT) fine-tuned on a CMU salsa pair
  (:func:`train_pair_forecasters`, :func:`pair_split`).

Sizes are constructor arguments with CPU-sized defaults; each private module lists its public names in
``__all__`` and they are re-exported here. The evaluation's orchestration, tables and figures
(``python -m experiments.dynamics``) live in :mod:`experiments.dynamics_study`.
"""

from importlib.metadata import version as _version

from ._attention import agent_masks as agent_masks
from ._attention import sinusoidal_encoding as sinusoidal_encoding
from ._attention import AgentAttention as AgentAttention
from ._attention import GPTLayer as GPTLayer
from ._attention import InputEncoder as InputEncoder
from ._attention import KeyValues as KeyValues
from ._backbone import Pooling as Pooling
from ._backbone import ResNetBackbone as ResNetBackbone
from ._canonical import canonical_features as canonical_features
from ._canonical import canonicalise as canonicalise
from ._canonical import JointAwareBias as JointAwareBias
from ._data import build_frames as build_frames
from ._data import check_validation_apart as check_validation_apart
from ._data import crop_square as crop_square
from ._data import gather_windows as gather_windows
from ._data import scene_windows as scene_windows
from ._data import square_boxes as square_boxes
from ._data import video_tracks as video_tracks
from ._data import window_starts as window_starts
from ._data import without_crops as without_crops
from ._data import DataConfig as DataConfig
from ._data import Frames as Frames
from ._data import TEST_MULTI_PERSON_CLIPS as TEST_MULTI_PERSON_CLIPS
from ._data import TEST_SINGLE_PERSON_CLIPS as TEST_SINGLE_PERSON_CLIPS
from ._data import TRAIN_CLIPS as TRAIN_CLIPS
from ._data import VALIDATION_DATA as VALIDATION_DATA
from ._evaluate import forecast_scenes as forecast_scenes
from ._evaluate import frame_metrics as frame_metrics
from ._evaluate import penetration_mm as penetration_mm
from ._evaluate import predict_windows as predict_windows
from ._evaluate import summarise as summarise
from ._evaluate import zero_motion as zero_motion
from ._evaluate import EvalConfig as EvalConfig
from ._evaluate import HORIZONS as HORIZONS
from ._evaluate import METRICS as METRICS
from ._evaluate import SCENE_BATCH as SCENE_BATCH
from ._forecast import constant_velocity_forecast as constant_velocity_forecast
from ._forecast import forecast_joints as forecast_joints
from ._forecast import zero_motion_forecast as zero_motion_forecast
from ._forecast import ForecasterConfig as ForecasterConfig
from ._forecast import PoseForecaster as PoseForecaster
from ._hmr import decoding_start as decoding_start
from ._hmr import mean_params as mean_params
from ._hmr import DecodeFrom as DecodeFrom
from ._hmr import HMRHead as HMRHead
from ._hmr import SMPLParams as SMPLParams
from ._jat import box_features as box_features
from ._jat import scene_tokens as scene_tokens
from ._jat import JAT as JAT
from ._jat import JATConfig as JATConfig
from ._losses import frame_losses as frame_losses
from ._losses import interpenetration as interpenetration
from ._losses import penetration_depths as penetration_depths
from ._losses import penetration_surfaces as penetration_surfaces
from ._losses import shape_consistency as shape_consistency
from ._losses import FrameTargets as FrameTargets
from ._losses import LossWeights as LossWeights
from ._losses import PenetrationSurfaces as PenetrationSurfaces
from ._losses import PENETRATION_POINTS as PENETRATION_POINTS
from ._phdt import crop_roots as crop_roots
from ._phdt import last_frame as last_frame
from ._phdt import params_to_joints as params_to_joints
from ._phdt import Observation as Observation
from ._phdt import PHDT as PHDT
from ._phdt import PHDTConfig as PHDTConfig
from ._phdt import Rollout as Rollout
from ._poses import canonical_window as canonical_window
from ._poses import mirror_frames as mirror_frames
from ._poses import pose_features as pose_features
from ._poses import pose_frames as pose_frames
from ._poses import FORECAST_FPS as FORECAST_FPS
from ._poses import FORECAST_HORIZONS_MS as FORECAST_HORIZONS_MS
from ._poses import POSE_FEATURES as POSE_FEATURES
from ._poses import PoseFrames as PoseFrames
from ._prior import lsgan_discriminator_loss as lsgan_discriminator_loss
from ._prior import lsgan_generator_loss as lsgan_generator_loss
from ._prior import PosePrior as PosePrior
from ._shipped import SHIPPED_FORECASTERS as SHIPPED_FORECASTERS
from ._shipped import SHIPPED_MODEL as SHIPPED_MODEL
from ._shipped import SHIPPED_TRANSFORMERS as SHIPPED_TRANSFORMERS
from ._tcn import CausalTCN as CausalTCN
from ._train import cached_features as cached_features
from ._train import check_crop_sizes as check_crop_sizes
from ._train import compute_features as compute_features
from ._train import conditioning_metrics as conditioning_metrics
from ._train import load_trained as load_trained
from ._train import mean_local_pose as mean_local_pose
from ._train import mean_pose_metrics as mean_pose_metrics
from ._train import train as train
from ._train import train_conditioning as train_conditioning
from ._train import BackboneConfig as BackboneConfig
from ._train import ImageRegressor as ImageRegressor
from ._train import StageConfig as StageConfig
from ._train import TrainConfig as TrainConfig
from ._train_forecast import canonical_scenes as canonical_scenes
from ._train_forecast import forecast_split as forecast_split
from ._train_forecast import initial_forecaster as initial_forecaster
from ._train_forecast import load_forecaster as load_forecaster
from ._train_forecast import load_forecasters as load_forecasters
from ._train_forecast import pair_split as pair_split
from ._train_forecast import scene_rows as scene_rows
from ._train_forecast import train_forecaster as train_forecaster
from ._train_forecast import train_forecasters as train_forecasters
from ._train_forecast import train_pair_forecasters as train_pair_forecasters
from ._train_forecast import FORECASTERS as FORECASTERS
from ._train_forecast import PAIR_FORECASTERS as PAIR_FORECASTERS
from ._train_forecast import ForecastTrainConfig as ForecastTrainConfig
from ._train_jat import as_multi_person as as_multi_person
from ._train_jat import load_transformers as load_transformers
from ._train_jat import train_all as train_all
from ._train_jat import train_transformer as train_transformer
from ._train_jat import TRANSFORMERS as TRANSFORMERS
from ._train_jat import TransformerTrainConfig as TransformerTrainConfig

__version__ = _version("mvmocap")
