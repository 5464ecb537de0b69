"""Multi-person dynamics models (PHD+T and its successors, Karia 2023): their neural building blocks in Flax NNX.

- :class:`ResNetBackbone`: a small ResNet (GroupNorm, no mutable state) from person crops to features phi.
- :class:`HMRHead`, :class:`SMPLParams`, :func:`mean_params`: the HMR regressor from features to SMPL pose (6D),
  shape and weak-perspective crop camera (:func:`geometry.crop_camera_to_translation` turns the camera into a
  full-perspective translation).
- :class:`CausalTCN`: PHD's temporal encoder (f_movie, f_AR), strictly causal.
- :class:`PosePrior`, :func:`lsgan_discriminator_loss`, :func:`lsgan_generator_loss`: HMR's 25 LSGAN
  discriminators on rotations and shape.

Sizes are constructor arguments with CPU-sized defaults; each private module lists its public names in
``__all__`` and they are re-exported here.
"""

from ._backbone import *  # noqa: F403
from ._hmr import *  # noqa: F403
from ._prior import *  # noqa: F403
from ._tcn import *  # noqa: F403
from ._attention import *  # noqa: F403
from ._canonical import *  # noqa: F403
from ._phdt import *  # noqa: F403
from ._losses import *  # noqa: F403
from ._data import *  # noqa: F403
from ._jat import *  # noqa: F403
from ._train import *  # noqa: F403
from ._train_jat import *  # noqa: F403
from ._evaluate import *  # noqa: F403
from ._report import *  # noqa: F403
from ._experiment import *  # noqa: F403
