"""Seg2Pose: world-coordinate pose tracks of road users from instance-segmentation masks.

The method of Ahrnbom, Persson and Nilsson, VISAPP 2022 (see ../shared/paper). This package
holds the maths and the pipeline and imports no UI: ``s2p_review`` (Rerun) and ``annotate``
build on it.
"""

from seg2pose.core.errors import InputError, S2PError

__version__ = "0.1.0"
__all__ = ["S2PError", "InputError", "__version__"]
