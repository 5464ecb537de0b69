"""The JCSAT Shelf study (``python -m experiments.shelf_jcsat``, ``experiments.shelf_validate``): the main job
that runs the model or the learning-free baseline on the real or a synthetic Shelf scene, writes and scores the
predictions, the synthetic validation of baseline settings and model aggregates, the one-frame figure, and the paper's
ablations (``python -m experiments.jcsat_ablations``)."""

from ._ablations import ABLATION_ROWS as ABLATION_ROWS
from ._ablations import ablation_table as ablation_table
from ._ablations import AblationRow as AblationRow
from ._ablations import run_ablations as run_ablations
from ._ablations import SHIPPED as SHIPPED
from ._ablations import VARIANTS as VARIANTS
from ._plot import matched_tracks as matched_tracks
from ._plot import plot_frame as plot_frame
from ._plot import MATCH_DISTANCE_M as MATCH_DISTANCE_M
from ._shelf import check_input_files as check_input_files
from ._shelf import run_shelf_experiment as run_shelf_experiment
from ._shelf import synthetic_validation as synthetic_validation
from ._shelf import METHODS as METHODS
from ._shelf import ShelfExperimentConfig as ShelfExperimentConfig
from ._shelf import ShelfExperimentResult as ShelfExperimentResult
