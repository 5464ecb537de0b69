"""The studies of Structural Triangulation: the virtual-camera experiment (``python -m experiments.structri_virtual``;
paper Sect. 4.1, Fig. 4 and Fig. 6, and the N-step study of Sect. 4.2), real CMU poses seen by the official virtual
rings, every solver scored against the ground truth and the certified reference; and the real-Shelf table
(``python -m experiments.structri_shelf``; the paper's Tables 1-4 in shape), every solver on the OpenPose
detections of the learning-free pipeline's tracks, scored against actorsGT."""

from ._virtual import load_poses as load_poses
from ._virtual import run_virtual as run_virtual
from ._virtual import write_report as write_report
from ._virtual import METHODS as METHODS
from ._virtual import ST_VARIANTS as ST_VARIANTS
from ._virtual import VirtualConfig as VirtualConfig
from ._shelf import run_shelf as run_shelf
from ._shelf import ShelfConfig as ShelfConfig
from ._shelf import SHELF_METHODS as SHELF_METHODS
from ._shelf import score_rows as score_rows
from ._shelf import ShelfScene as ShelfScene
from ._shelf import solvable as solvable
