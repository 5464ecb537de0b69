"""FLEX's synthetic experiment (``python -m experiments.flex_synthetic``): FLEX against camera-dependent
triangulation on held-out CMU clips with static and moving cameras (paper Tables 1, 3 and 5), its tables and
figures, and the training of the experiment's models (:data:`flex.MODELS`, :data:`flex.RIG_MODELS`,
:data:`flex.DETECTION_MODELS`); FLEX on the real Shelf detections (``python -m experiments.flex_shelf``)."""

from ._synthetic import plot_camera_poses as plot_camera_poses
from ._synthetic import run_experiment as run_experiment
from ._synthetic import train_config as train_config
from ._synthetic import train_models as train_models
from ._synthetic import ExperimentConfig as ExperimentConfig
from ._synthetic import RIG_NOISE_CORRELATION as RIG_NOISE_CORRELATION
from ._shelf import flex_poses as flex_poses
from ._shelf import run_flex_shelf as run_flex_shelf
from ._shelf import FlexShelfConfig as FlexShelfConfig
