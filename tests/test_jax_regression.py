"""Guards against the jaxlib 0.10.2 CPU miscompilation of jitted broadcast-multiply-reduce code.

jaxlib 0.10.2 routes some jitted reductions to its new YNNPACK fusion and returns wrong numbers,
with no error, once the batch is larger than about 10k (jax-ml/jax#39103). The project disables that fusion with
``XLA_FLAGS=--xla_cpu_experimental_ynn_fusion_type=``, set explicitly by ``geometry.disable_faulty_cpu_fusion()``
(geometry/_jax_guard.py; tests/conftest.py calls it), refuses 0.10.2 without it at ``import geometry``, and excludes
the version in pyproject.toml. These tests fail if a jax bump brings the bug back.
"""

import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from _compile_flags import FAST_COMPILE_FLAGS, user_environment
from geometry import triangulate
from geometry._jax_guard import YNN_FUSION_OFF as WORKAROUND
from geometry._triangulate import _triangulate_flat

# Minimal repro of jax-ml/jax#39103: sum over axis 0 of a[:, :, None, :] * a[:, None, :, :]; sets ``error``. Run in this
# process (broadcast_multiply_reduce_error) and, with an exit status, in fresh interpreters (REPRO_COMMAND).
REPRO = """
import jax
import numpy as np
a = np.random.default_rng(0).uniform(size=(4, 4, 100_000)).astype(np.float32)
jitted = np.asarray(jax.jit(lambda a: (a[:, :, None, :] * a[:, None, :, :]).sum(axis=0))(a))
error = float(np.abs(jitted - np.einsum("kin,kjn->ijn", a, a)).max())
"""
REPRO_COMMAND = REPRO + """
import sys
print(f"jaxlib {jax.lib.__version__ if hasattr(jax.lib, '__version__') else '?'}: max error {error:.3g}")
sys.exit(0 if error < 1e-4 else 1)
"""


def _without_workaround() -> dict[str, str]:
    """The project's configuration (tests/_compile_flags.py) without the workaround."""
    env = user_environment(JAX_PLATFORMS="cpu")
    return {**env, "XLA_FLAGS": " ".join(flag for flag in env["XLA_FLAGS"].split() if flag != WORKAROUND)}


def _run(code: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)


def broadcast_multiply_reduce_error() -> float:
    scope = {}
    exec(REPRO, scope)
    return scope["error"]


def test_installed_jaxlib_has_no_ynn_fusion_miscompilation():
    """The repro in a fresh interpreter whose XLA_FLAGS lack the workaround.

    The flag only takes effect before jax initialises its backend, and this process (like every
    project entry point) already runs with it, which would hide the bug. A subprocess with the flag
    removed from its environment therefore tests the installed jaxlib itself: it fails on 0.10.2
    (every element wrong, max error ~35) and passes on 0.10.1."""
    done = _run(REPRO_COMMAND, _without_workaround())
    assert done.returncode == 0, f"installed jaxlib miscompiles the repro without {WORKAROUND}:\n{done.stdout}{done.stderr}"


def test_importing_geometry_leaves_xla_flags_alone():
    env = _without_workaround()
    done = _run("import os, geometry; print(repr(os.environ['XLA_FLAGS']))", env)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == repr(env["XLA_FLAGS"])


def test_disable_faulty_cpu_fusion_sets_the_flag_only_before_jax_computes():
    before = ("import os, geometry; print(geometry.disable_faulty_cpu_fusion(), "
              "os.environ['XLA_FLAGS'].split()[-1])")
    done = _run(before, _without_workaround())
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["True", WORKAROUND]
    # Too late once jax has computed: the call says so and changes nothing.
    after = ("import os, jax.numpy as jnp, geometry; jnp.ones(2).sum().block_until_ready(); "
             "print(geometry.disable_faulty_cpu_fusion(), repr(os.environ['XLA_FLAGS']))")
    env = _without_workaround()
    done = _run(after, env)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().split(maxsplit=1) == ["False", repr(env["XLA_FLAGS"])]


# Pretends jaxlib 0.10.2 is installed, then imports geometry.
_AS_IF_FAULTY_JAXLIB = """
import importlib.metadata as metadata
installed = metadata.version
metadata.version = lambda name: "0.10.2" if name == "jaxlib" else installed(name)
import geometry
"""


def test_geometry_refuses_faulty_jaxlib_without_the_flag():
    done = _run(_AS_IF_FAULTY_JAXLIB, _without_workaround())
    assert done.returncode != 0
    last_line = done.stderr.strip().splitlines()[-1]
    assert last_line.startswith("ImportError: jaxlib 0.10.2 miscompiles") and f"XLA_FLAGS={WORKAROUND}" in last_line
    env = _without_workaround()
    env["XLA_FLAGS"] = f"{env['XLA_FLAGS']} {WORKAROUND}"
    assert _run(_AS_IF_FAULTY_JAXLIB, env).returncode == 0


def test_tests_compile_fast_and_user_commands_as_users_run_them():
    """The suite compiles with tests/_compile_flags.py's flags; the commands run as a user runs them keep the
    project's configuration, the workaround included, without them."""
    assert set(FAST_COMPILE_FLAGS) <= set(os.environ["XLA_FLAGS"].split())
    user_flags = user_environment()["XLA_FLAGS"].split()
    assert WORKAROUND in user_flags and not set(FAST_COMPILE_FLAGS) & set(user_flags)


def test_repro_is_exact_with_the_project_configuration():
    """The repro in a fresh interpreter with the project's configuration (the workaround on, XLA's defaults
    otherwise), and in this test process (the workaround on, tests/_compile_flags.py's flags)."""
    env = user_environment(JAX_PLATFORMS="cpu")
    assert WORKAROUND in env["XLA_FLAGS"].split()
    done = _run(REPRO_COMMAND, env)
    assert done.returncode == 0, done.stdout + done.stderr
    assert WORKAROUND in os.environ.get("XLA_FLAGS", "").split()
    assert broadcast_multiply_reduce_error() < 1e-4


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_triangulation_under_jit_equals_eager_at_100k_points(dtype):
    """How the bug first showed: the element-wise DLT kernel went wrong for N >= ~10k under jit."""
    rng = np.random.default_rng(0)
    projections = np.array(
        [
            [[900.0, 0.0, 640.0, 0.0], [0.0, 900.0, 360.0, 0.0], [0.0, 0.0, 1.0, 0.0]],
            [[900.0, 0.0, 640.0, -450.0], [0.0, 900.0, 360.0, 0.0], [0.0, 0.0, 1.0, 0.0]],
        ],
        dtype,
    )
    points = rng.uniform([-1, -1, 3], [1, 1, 9], (100_000, 3))
    homogeneous = np.einsum("vij,nj->nvi", projections.astype(np.float64), np.column_stack([points, np.ones(len(points))]))
    pixels = (homogeneous[..., :2] / homogeneous[..., 2:] + rng.normal(0, 0.5, (len(points), 2, 2))).astype(dtype)
    weights = np.ones((len(points), 2), dtype)
    jitted = triangulate(projections, pixels, weights)
    with jax.disable_jit():
        eager = _triangulate_flat(jnp.asarray(projections), jnp.asarray(pixels), jnp.asarray(weights), "closed_form", False, 1e4, True)
    assert bool(jitted.valid.all()) and bool(eager.valid.all())
    tolerance = 1e-9 if dtype == np.float64 else 1e-3
    np.testing.assert_allclose(jitted.point, eager.point, rtol=tolerance, atol=tolerance)
    np.testing.assert_allclose(jitted.point, points, atol=1.0)  # both right, not merely equal
