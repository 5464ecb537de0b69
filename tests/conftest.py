"""Test configuration: strict numerics and the data folder.

The XLA flag must be in the environment before jax initialises its backend (see
``tests/test_jax_regression.py``), so it is set before anything imports jax.
"""

import os

_FLAG = "--xla_cpu_experimental_ynn_fusion_type="
if _FLAG not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_FLAG}".strip()

from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import pytest  # noqa: E402

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
