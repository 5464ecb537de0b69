"""The XLA flags the test processes compile with, and the environment of a command run as a user runs it.

The suite is bound by XLA's CPU compilation (about two thirds of the tests' time in a profiled run on the 2-core VM,
2026-11-27), and two flags cut it: LLVM optimisation level 1 instead of 2, and XLA's older fusion code generator
instead of its MLIR fusion emitters. ``pytest tests/test_flex_model.py`` on that VM under each ``XLA_FLAGS``: 92-135 s
with the defaults (four runs), 52-61 s with both flags (two runs), 80-93 s with the emitters off alone (three runs);
the whole suite (two workers, every command under the flags): the tests' summed time 3085 s -> 2065 s. Level 0
compiles faster still, but it ran the Shelf model 4.8 times slower and moved two pinned results, so it is not used.
The flags change floating-point rounding, not semantics (no fast math), so the numerical tests hold under them; the
project's entry points keep XLA's defaults, the configuration every reported number was computed with, and the
headline pins (tests/test_headline_results.py), the README's examples (tests/test_docs.py) and the jaxlib regression
guard start their subprocesses in that configuration (:func:`user_environment`).
"""

import os

FAST_COMPILE_FLAGS = ("--xla_backend_optimization_level=1", "--xla_cpu_use_fusion_emitters=false")


def with_fast_compilation(flags: str) -> str:
    """``flags`` (an ``XLA_FLAGS`` value) with :data:`FAST_COMPILE_FLAGS` added once."""
    present = flags.split()
    return " ".join(present + [flag for flag in FAST_COMPILE_FLAGS if flag not in present])


def user_environment(**overrides: str) -> dict[str, str]:
    """This process's environment with :data:`FAST_COMPILE_FLAGS` removed from ``XLA_FLAGS``, then ``overrides``."""
    flags = " ".join(flag for flag in os.environ.get("XLA_FLAGS", "").split() if flag not in FAST_COMPILE_FLAGS)
    return {**os.environ, "XLA_FLAGS": flags, **overrides}
