"""Motion sources, multi-view scene synthesis with a 2D detector model, and real-dataset loaders."""

from ._detections import *  # noqa: F403
