"""Reconstruction of a user's own recording (``python -m experiments.reconstruct``): calibration and 2D detection
files in the formats of EasyMocap, anipose, OpenPose and mmpose in; predictions, per-frame JSON, one BVH per person,
an interactive HTML viewer, an animation and a figure out."""

from ._reconstruct import ReconstructConfig as ReconstructConfig
from ._reconstruct import run_reconstruction as run_reconstruction
