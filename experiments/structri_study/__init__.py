"""The virtual-camera experiment of Structural Triangulation (``python -m experiments.structri_virtual``; paper
Sect. 4.1, Fig. 4 and Fig. 6): real CMU poses seen by the official virtual rings, every solver scored against
the ground truth and the certified reference, written as tables and plots."""

from ._virtual import load_poses as load_poses
from ._virtual import run_virtual as run_virtual
from ._virtual import write_report as write_report
from ._virtual import METHODS as METHODS
from ._virtual import VirtualConfig as VirtualConfig
