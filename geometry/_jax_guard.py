"""Refuse jaxlib 0.10.2 on CPU unless its miscompiling YNNPACK fusion is switched off.

jaxlib 0.10.2 returns wrong numbers, silently, for jitted broadcast-multiply-reduce code on CPU
(jax-ml/jax#39103), which is the shape of our element-wise triangulation kernels. pyproject.toml
excludes that version; this guard covers environments installed by other means.
"""

import os
from importlib.metadata import PackageNotFoundError, version

_FLAG = "--xla_cpu_experimental_ynn_fusion_type="

try:
    _jaxlib = version("jaxlib")
except PackageNotFoundError:  # pragma: no cover - jax always brings jaxlib
    _jaxlib = ""

if _jaxlib == "0.10.2" and _FLAG not in os.environ.get("XLA_FLAGS", "").split():
    raise ImportError(
        "jaxlib 0.10.2 miscompiles jitted reductions on CPU (jax-ml/jax#39103). Install "
        "'jax!=0.10.2' (pip install 'jax==0.10.1' 'jaxlib==0.10.1') or set "
        f"XLA_FLAGS={_FLAG} before Python starts."
    )
