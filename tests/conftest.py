"""Test configuration: strict numerics and the data folder.

``geometry`` is imported before any computation: it sets the XLA flag that must be in the environment before jax
initialises its backend (see ``geometry/_jax_guard.py`` and ``tests/test_jax_regression.py``).
"""

import gc
import os
from pathlib import Path

import jax
import pytest

import geometry  # noqa: F401  (switches off jaxlib 0.10.2's faulty CPU fusion before jax computes)

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

REPO = Path(__file__).resolve().parents[1]


def pytest_addoption(parser):
    parser.addoption(
        "--data-root",
        default=os.environ.get("MVMOCAP_DATA_ROOT", str(REPO.parent / "shared" / "data")),
        help="folder with shelf/, campus/ and cmu_mocap/ (tests that need it are skipped without it)",
    )


@pytest.fixture(scope="session")
def data_root(request) -> Path:
    """The real data folder; skips the test with the reason when it is absent."""
    root = Path(request.config.getoption("--data-root")).expanduser()
    if not (root / "shelf").is_dir():
        pytest.skip(f"real data not found at {root} (pass --data-root or set MVMOCAP_DATA_ROOT)")
    return root


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_code():
    """Drop every compiled program after each test module.

    Each compiled CPU executable keeps its own memory mappings alive; one process running the whole suite
    crossed the kernel's ``vm.max_map_count`` (65530 by default) and XLA then segfaulted while compiling.
    """
    yield
    jax.clear_caches()
    gc.collect()
