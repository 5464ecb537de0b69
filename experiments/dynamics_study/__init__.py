"""The dynamics evaluations: ``python -m experiments.dynamics``, the models and ZeroMotion on held-out synthetic
videos, written as tables (Tables 5.2-5.11's layout), prediction plots (Fig. 5.1) and a strip of observed and
predicted meshes rendered into the video frames; ``python -m experiments.dynamics_forecast``, the 3D forecasters
and two baselines on the CMU-Mocap benchmark's motion, per action and horizon; ``python -m
experiments.dynamics_seeds``, the tables of either as mean and spread over training seeds; ``python -m
experiments.dynamics_renders``, the motion, renders and mirrors per training clip and the conditioning stage's steps,
chosen on validation."""

from ._evaluation import run_experiment as run_experiment
from ._evaluation import write_strip as write_strip
from ._evaluation import STRIP_FRAMES as STRIP_FRAMES
from ._evaluation import STRIP_SIZE as STRIP_SIZE
from ._forecast import forecast_markdown as forecast_markdown
from ._forecast import plot_forecast as plot_forecast
from ._forecast import run_forecast_study as run_forecast_study
from ._forecast import BASELINES as BASELINES
from ._renders import renders_markdown as renders_markdown
from ._renders import Flips as Flips
from ._renders import renders_summary as renders_summary
from ._renders import run_renders_study as run_renders_study
from ._report import overlay_meshes as overlay_meshes
from ._report import plot_prediction as plot_prediction
from ._report import results_markdown as results_markdown
from ._seeds import forecast_seeds_markdown as forecast_seeds_markdown
from ._seeds import forecast_seeds_summary as forecast_seeds_summary
from ._seeds import seeds_markdown as seeds_markdown
from ._seeds import seeds_summary as seeds_summary
