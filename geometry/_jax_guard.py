"""Keep jaxlib 0.10.2's CPU miscompilation away from the project, without touching global state at import.

jaxlib 0.10.2 returns wrong numbers, silently, for jitted broadcast-multiply-reduce code on CPU
(jax-ml/jax#39103), the shape of our element-wise triangulation kernels; its YNNPACK fusion pass is
the cause, and ``XLA_FLAGS=--xla_cpu_experimental_ynn_fusion_type=`` switches it off. pyproject.toml
excludes that version. Importing ``geometry`` only refuses 0.10.2 when the flag is not set; it never
writes the environment itself. Entry points, notebooks and tests/conftest.py call
:func:`disable_faulty_cpu_fusion` explicitly before jax computes anything: the flag is harmless on other
versions, made the element-wise kernels faster on 0.10.x, and is the configuration the project's
reported numbers were computed with. tests/test_jax_regression.py guards both halves.
"""

import os
from importlib.metadata import PackageNotFoundError, version

__all__ = ["disable_faulty_cpu_fusion"]

YNN_FUSION_OFF = "--xla_cpu_experimental_ynn_fusion_type="
_FAULTY_JAXLIB = "0.10.2"


def _backend_initialised() -> bool:
    try:
        from jax._src import xla_bridge
    except ImportError:  # pragma: no cover - private module moved: assume the worst
        return True
    return xla_bridge.backends_are_initialized()


def _flag_active() -> bool:
    return YNN_FUSION_OFF in os.environ.get("XLA_FLAGS", "").split()


def disable_faulty_cpu_fusion() -> bool:
    """Switch XLA's YNNPACK CPU fusion off for this process (adds ``--xla_cpu_experimental_ynn_fusion_type=``
    to ``os.environ["XLA_FLAGS"]``; subprocesses started later inherit it).

    XLA reads its flags once, when jax initialises its backend, i.e. at the first computation (importing jax
    does not initialise it). So call this at the top of an entry point, notebook or test configuration, before
    anything computes. Returns whether the flag is in effect: True when it was already set or is set now,
    False when jax already computed without it (nothing is changed then; restart the process).
    """
    if _flag_active():
        return True
    if _backend_initialised():
        return False
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {YNN_FUSION_OFF}".strip()
    return True


def _installed_jaxlib() -> str:
    try:
        return version("jaxlib")
    except PackageNotFoundError:  # pragma: no cover - jax always brings jaxlib
        return ""


if _installed_jaxlib() == _FAULTY_JAXLIB and not _flag_active():
    raise ImportError(
        f"jaxlib {_FAULTY_JAXLIB} miscompiles jitted reductions on CPU (jax-ml/jax#39103). Install another version "
        "(pip install 'jax==0.10.1' 'jaxlib==0.10.1'), or switch the faulty pass off before jax computes: "
        f"XLA_FLAGS={YNN_FUSION_OFF} in the environment before Python starts."
    )
