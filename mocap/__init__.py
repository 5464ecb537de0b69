"""Motion sources, multi-view scene synthesis with a 2D detector model, a mesh rasteriser, and real-dataset loaders."""

from ._detections import *  # noqa: F403
from ._shelf_campus import *  # noqa: F403
from ._predictions import *  # noqa: F403
from ._evaluation import *  # noqa: F403
from ._motion import *  # noqa: F403
from ._asf_amc import *  # noqa: F403
from ._bvh import *  # noqa: F403
from ._clips import *  # noqa: F403
from ._data_root import find_data_root as find_data_root
from ._procedural import *  # noqa: F403
from ._detector import *  # noqa: F403
from ._scene import *  # noqa: F403
from ._render import *  # noqa: F403
from ._retarget import *  # noqa: F403
from ._video import *  # noqa: F403
