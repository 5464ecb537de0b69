"""JCSAT (Jiang et al., TVCG 2025): the OTAP Sinkhorn aggregation and the transformer (paper Sec. 3.2-3.4), its
losses, synthetic training data and training loop, reading a trained model back (:func:`load_model`), and
inference on tracked people (:func:`predict_shelf15`) and the whole multi-person pipeline on arrays
(:func:`reconstruct`).

The model's input, the Joint Cloud of each tracked person (paper Sec. 3.1 and Algorithm 1), is built by the
learning-free multi-person pipeline of :mod:`association` (:func:`association.track_people`), which also holds the
geometric baseline.
"""

from importlib.metadata import version as _version

from ._data import Batch as Batch
from ._data import build_dataset as build_dataset
from ._data import DataConfig as DataConfig
from ._data import sample_batch as sample_batch
from ._data import scene_windows as scene_windows
from ._data import TRAIN_CLIPS as TRAIN_CLIPS
from ._data import VALIDATION_CLIPS as VALIDATION_CLIPS
from ._data import window_batch as window_batch
from ._data import WindowDataset as WindowDataset
from ._inference import AGGREGATES as AGGREGATES
from ._inference import DEFAULT_AGGREGATE as DEFAULT_AGGREGATE
from ._inference import DEFAULT_WINDOW_STRIDE as DEFAULT_WINDOW_STRIDE
from ._inference import predict_shelf15 as predict_shelf15
from ._inference import reconstruct as reconstruct
from ._inference import Reconstruction as Reconstruction
from ._losses import bone_losses as bone_losses
from ._losses import jcsat_loss as jcsat_loss
from ._losses import LossConfig as LossConfig
from ._losses import pcp_hinge_loss as pcp_hinge_loss
from ._losses import project_normalised as project_normalised
from ._losses import projection_loss as projection_loss
from ._losses import reconstruction_loss as reconstruction_loss
from ._model import aggregation_variant as aggregation_variant
from ._model import CONFIGS as CONFIGS
from ._model import JCSAT as JCSAT
from ._model import JCSATConfig as JCSATConfig
from ._model import load_model as load_model
from ._model import parameter_count as parameter_count
from ._model import SHIPPED_MODEL as SHIPPED_MODEL
from ._otap import OTAP as OTAP
from ._otap import otap as otap
from ._otap import sinkhorn_plan as sinkhorn_plan
from ._train import init_state as init_state
from ._train import learning_rate_schedule as learning_rate_schedule
from ._train import make_optimiser as make_optimiser
from ._train import train as train
from ._train import TRAIN_CONFIGS as TRAIN_CONFIGS
from ._train import train_step as train_step
from ._train import TrainConfig as TrainConfig
from ._train import validate as validate
from ._train import TrainState as TrainState

__version__ = _version("mvmocap")
