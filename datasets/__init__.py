"""datasets: loaders for the real file formats of depth-from-defocus datasets, and focus synthesis.

Not Hugging Face's `datasets`: never install that package in this environment.
"""

from optics import collate  # the collate function of data loaders over these datasets

from .base import DepthDataset
from .ddff12 import DDFF12
from .dslr import DSLR
from .focus import CameraPreset, SynthesizedFocus, cached_focal_stack
from .fod500 import FoD500
from .io import DataFormatError
from .kitti import KITTI
from .lightfield import LightField, LightFieldCalibration, refocus
from .make3d import Make3D
from .middlebury import Middlebury
from .mobile_depth import MobileDepth
from .nyu import NYUv2
from .photo_folder import PhotoFolder
from .presets import PRESETS
from .rgbd import RGBD
from .stacks import FocalStackDataset
from .transforms import JointAugment
from .zedd import ZEDD

__all__ = [
    "DDFF12",
    "DSLR",
    "KITTI",
    "PRESETS",
    "CameraPreset",
    "DataFormatError",
    "DepthDataset",
    "FoD500",
    "FocalStackDataset",
    "JointAugment",
    "LightField",
    "LightFieldCalibration",
    "Make3D",
    "Middlebury",
    "MobileDepth",
    "NYUv2",
    "PhotoFolder",
    "RGBD",
    "SynthesizedFocus",
    "ZEDD",
    "cached_focal_stack",
    "collate",
    "refocus",
]
