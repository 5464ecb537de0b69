"""tests/conftest.py: under CI a missing data folder fails the whole run; elsewhere its tests are skipped; each
test process compiles into its own persistent cache."""

import os
import subprocess
import sys
from pathlib import Path

import jax
import pytest

REPO = Path(__file__).resolve().parents[1]


def _collect_with(ci: str | None, data_root: Path) -> subprocess.CompletedProcess:
    """Collects this module (collection alone runs conftest's checks) in a fresh pytest with ``CI`` as given."""
    env = {key: value for key, value in os.environ.items() if key not in ("CI", "MVMOCAP_DATA_ROOT")}
    env["PYTHONPATH"] = str(REPO)
    if ci is not None:
        env["CI"] = ci
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "--collect-only", "-p", "no:cacheprovider",
         f"--data-root={data_root}", str(Path(__file__).relative_to(REPO))],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=300)


def test_ci_without_data_fails_at_session_start_with_one_line(tmp_path):
    run = _collect_with("true", tmp_path / "absent")
    assert run.returncode == pytest.ExitCode.USAGE_ERROR, run.stdout + run.stderr
    errors = [line for line in (run.stdout + run.stderr).splitlines() if line.strip()]
    assert errors == [f"ERROR: CI=true and real data not found at {tmp_path / 'absent'} "
                      "(pass --data-root or set MVMOCAP_DATA_ROOT)"]


def test_without_ci_a_missing_data_folder_only_skips_its_tests(tmp_path):
    run = _collect_with(None, tmp_path / "absent")
    assert run.returncode == pytest.ExitCode.OK, run.stdout + run.stderr


@pytest.mark.skipif("PYTEST_XDIST_WORKER" not in os.environ, reason="one test process: there is no cache to share")
def test_each_test_process_has_its_own_compilation_cache():
    # jax writes cache entries in place without a lock, so two processes sharing a folder can read half an entry.
    assert Path(jax.config.jax_compilation_cache_dir).name == os.environ["PYTEST_XDIST_WORKER"]
