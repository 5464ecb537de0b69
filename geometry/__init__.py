"""The shared geometry core: cameras, projection, triangulation, rotations, skeletons, kinematics, body model,
body capsules (signed distance and interpenetration), metrics.

Every public function is pure and written for one item (one point, one camera, one pose), with
shapes and units in its jaxtyping signature; batch with ``jax.vmap`` and compile with ``jax.jit``.
Each private module lists its public names in ``__all__``; they are re-exported here.
"""

from . import _jax_guard  # noqa: F401  (refuses the miscompiling jaxlib before any kernel runs)
from ._body import *  # noqa: F403
from ._calibration_io import *  # noqa: F403
from ._camera import *  # noqa: F403
from ._capsules import *  # noqa: F403
from ._convert import *  # noqa: F403
from ._kinematics import *  # noqa: F403
from ._metrics import *  # noqa: F403
from ._rigs import *  # noqa: F403
from ._rotations import *  # noqa: F403
from ._skeleton import *  # noqa: F403
from ._triangulate import *  # noqa: F403
