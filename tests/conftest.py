"""Test configuration: strict numerics and the data folder.

``geometry.disable_faulty_cpu_fusion()`` is called before any computation: it sets the XLA flag that must be in the
environment before jax initialises its backend (see ``geometry/_jax_guard.py`` and ``tests/test_jax_regression.py``);
subprocesses and notebook kernels started by the tests inherit it, and the test processes compile with
``tests/_compile_flags.py``'s flags (a shorter suite; commands pinned as a user runs them go without them).
"""

import gc
import os
import shutil
import tempfile
from pathlib import Path

from _compile_flags import with_fast_compilation

# One persistent compilation cache per test process, set in the environment before jax starts so that the
# process's subprocesses (two-device runs) and notebook kernels share it: each module's compiled programs are dropped
# after it (below), and later modules and runs that build the same programs load them instead of compiling
# them again. A fresh folder per run unless JAX_COMPILATION_CACHE_DIR is set, so a run's time is a cold start.
# Each pytest-xdist worker gets its own subfolder because jax writes an entry in place, without a lock: two
# workers collecting the same module compile the same program at once, and one read the other's half-written
# entry (a CI failure, "incomplete or truncated stream").
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    _COMPILED = tempfile.mkdtemp(prefix="mvmocap-compiled-")
    os.environ["JAX_COMPILATION_CACHE_DIR"] = _COMPILED
if "PYTEST_XDIST_WORKER" in os.environ:
    os.environ["JAX_COMPILATION_CACHE_DIR"] = os.path.join(
        os.environ["JAX_COMPILATION_CACHE_DIR"], os.environ["PYTEST_XDIST_WORKER"])
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")
# Compile for a short suite (tests/_compile_flags.py says why and what keeps the defaults); inherited like the above.
os.environ["XLA_FLAGS"] = with_fast_compilation(os.environ.get("XLA_FLAGS", ""))

import jax  # noqa: E402
import pytest  # noqa: E402

import geometry  # noqa: E402

if not geometry.disable_faulty_cpu_fusion():
    raise RuntimeError("jax computed before tests/conftest.py could switch its faulty CPU fusion off")

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")



def pytest_addoption(parser):
    parser.addoption(
        "--data-root",
        default=os.environ.get("MVMOCAP_DATA_ROOT", ""),
        help="folder with shelf/, campus/ and cmu_mocap/ (tests that need it are skipped without it; "
             "with CI=true in the environment its absence fails the run)",
    )


def _data_root(config) -> Path | None:
    """The folder the run was given (``make test`` passes ``DATA_ROOT``) if it holds ``shelf/``; nothing is guessed."""
    option = config.getoption("--data-root")
    root = Path(option).expanduser() if option else None
    return root if root is not None and (root / "shelf").is_dir() else None


def _missing_data(config) -> str:
    option = config.getoption("--data-root")
    where = f"at {option}" if option else "(no --data-root given and MVMOCAP_DATA_ROOT unset)"
    return f"real data not found {where} (pass --data-root or set MVMOCAP_DATA_ROOT)"


def pytest_configure(config):
    # Under CI the real-data tests pin the headline results (tests/test_headline_results.py): skipping them
    # because the data folder is missing would pass CI without checking them, so the whole run fails instead.
    if os.environ.get("CI", "").lower() == "true" and _data_root(config) is None:
        raise pytest.UsageError(f"CI=true and {_missing_data(config)}")


@pytest.fixture(scope="session")
def data_root(request) -> Path:
    """The real data folder; skips the test with the reason when it is absent (outside CI, see above)."""
    root = _data_root(request.config)
    if root is None:
        pytest.skip(_missing_data(request.config))
    return root


# The longest modules, longest first: their summed test times in one two-process run on the 2-core VM (2026-11-28,
# 22 min 40 s, 2620 s of tests; the headline module 563 s, the last listed here 22 s). `make test` hands whole modules
# to its two processes in collection order (--no-loadscope-reorder; xdist's own order is by test count, which ran the
# longest modules last, one process idle while the other finished them); the short rest fill in at the end.
_LONGEST_FIRST = (
    "test_headline_results.py", "test_jcsat_train.py", "test_structri.py", "test_jcsat_inference.py",
    "test_dynamics_train.py", "test_dynamics_forecast.py", "test_notebooks.py", "test_flex_train.py",
    "test_jcsat_model.py", "test_flex_model.py", "test_triangulate.py", "test_structri_shelf.py", "test_reconstruct.py",
    "test_jat.py", "test_jcsat_ablations.py", "test_geometric_baseline.py", "test_docs.py", "test_dynamics.py",
    "test_dynamics_defects.py", "test_joint_cloud.py", "test_flex_experiment.py", "test_flex_baselines.py",
    "test_public_api.py", "test_otap.py",
)


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(_LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: each module keeps its order


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_code():
    """Drop every compiled program after each test module.

    Each compiled CPU executable keeps its own memory mappings alive; one process running the whole suite
    crossed the kernel's ``vm.max_map_count`` (65530 by default) and XLA then segfaulted while compiling.
    """
    yield
    jax.clear_caches()
    gc.collect()


def pytest_sessionfinish(session, exitstatus):
    if "_COMPILED" in globals():
        shutil.rmtree(_COMPILED, ignore_errors=True)
