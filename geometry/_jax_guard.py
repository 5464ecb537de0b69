"""Keep jaxlib 0.10.2's CPU miscompilation away from every entry point that imports ``geometry``.

jaxlib 0.10.2 returns wrong numbers, silently, for jitted broadcast-multiply-reduce code on CPU
(jax-ml/jax#39103), the shape of our element-wise triangulation kernels; its YNNPACK fusion pass is
the cause. pyproject.toml excludes that version. Importing ``geometry`` also switches the pass off
through ``XLA_FLAGS``, which works only before jax initialises its backend (importing jax does not
initialise it; the first computation does), so scripts and notebooks import ``geometry`` (or a
package built on it) before they compute anything. The flag is harmless on other versions and made
the element-wise kernels faster on 0.10.x. tests/test_jax_regression.py guards both halves.
"""

import os
from importlib.metadata import PackageNotFoundError, version

YNN_FUSION_OFF = "--xla_cpu_experimental_ynn_fusion_type="


def _backend_initialised() -> bool:
    try:
        from jax._src import xla_bridge
    except ImportError:  # pragma: no cover - private module moved: assume the worst
        return True
    return xla_bridge.backends_are_initialized()


def _flag_active() -> bool:
    return YNN_FUSION_OFF in os.environ.get("XLA_FLAGS", "").split()


if not _flag_active() and not _backend_initialised():
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {YNN_FUSION_OFF}".strip()

try:
    _jaxlib = version("jaxlib")
except PackageNotFoundError:  # pragma: no cover - jax always brings jaxlib
    _jaxlib = ""

if _jaxlib == "0.10.2" and not _flag_active():  # jax started computing before we could set it
    raise ImportError(
        "jaxlib 0.10.2 miscompiles jitted reductions on CPU (jax-ml/jax#39103) and jax was "
        "initialised before `geometry` could switch the faulty pass off. Install 'jax!=0.10.2' "
        f"(pip install 'jax==0.10.1' 'jaxlib==0.10.1') or set XLA_FLAGS={YNN_FUSION_OFF} before Python starts."
    )
