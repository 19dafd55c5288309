"""datasets: loaders for the real file formats of depth-from-defocus datasets, and focus synthesis.

Not Hugging Face's `datasets`: never install that package in this environment.
"""

from .base import DepthDataset
from .dslr import DSLR
from .focus import CameraPreset, cached_focal_stack
from .io import DataFormatError
from .kitti import KITTI
from .lightfield import LightField, LightFieldCalibration, refocus
from .make3d import Make3D
from .middlebury import Middlebury
from .nyu import NYUv2
from .presets import PRESETS
from .transforms import JointAugment

__all__ = [
    "DSLR",
    "KITTI",
    "PRESETS",
    "CameraPreset",
    "DataFormatError",
    "DepthDataset",
    "JointAugment",
    "LightField",
    "LightFieldCalibration",
    "Make3D",
    "Middlebury",
    "NYUv2",
    "cached_focal_stack",
    "refocus",
]
