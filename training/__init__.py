"""Training infrastructure shared by every model of the project (JCSAT, FLEX, the dynamics models).

- :func:`run_training`: the resumable loop: orbax checkpoints written atomically every interval (a killed
  run loses at most one interval), ``--resume`` that continues bit-identically (refusing another config by the
  fields that differ), JSON-lines logs, a tqdm bar, validation at fixed steps. The model-specific step and
  validation are functions passed in. :func:`check_same_run` applies its rule to a finished run's model.
- :func:`data_parallel_shardings`: the one-axis ``"data"`` mesh over the local devices (batches sharded
  along their first axis, parameters and optimiser state replicated).
- :func:`save_model` / :func:`load_model_state`: a trained NNX model as ``config.json`` + ``state.npz``, the
  small format the project ships its models in; :func:`store_model_as` rewrites one in float16 (half the size);
  :func:`read_model_arrays` reads one's arrays without building the model.
- :func:`dropout`: inverted dropout driven by an explicit key (``None``: inference).
- :func:`process_map`: data building in CPU-only worker processes (samples and scenes are independent).
"""

from importlib.metadata import version as _version

from ._files import write_atomically as write_atomically
from ._layers import dropout as dropout
from ._loop import check_same_run as check_same_run
from ._loop import data_parallel_shardings as data_parallel_shardings
from ._loop import run_training as run_training
from ._loop import to_jsonable as to_jsonable
from ._provenance import provenance as provenance
from ._provenance import SIMD_FEATURES as SIMD_FEATURES
from ._store import load_model_state as load_model_state
from ._store import read_model_arrays as read_model_arrays
from ._store import save_model as save_model
from ._store import STORAGE_DTYPES as STORAGE_DTYPES
from ._store import store_model_as as store_model_as
from ._workers import process_map as process_map

__version__ = _version("mvmocap")
