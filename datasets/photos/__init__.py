"""Photos: one decoder for every loader and for `defocus predict` (`read_photo`, one path for
the EXIF orientation), what photo files state (`read_metadata`), raw files (`read_raw`), the
camera settings they give (`resolve_settings`) and the camera file (`CameraFile`).

Modules: `decode` (JPEG, PNG, TIFF and raw photos as linear RGB, upright), `metadata` (the
`PhotoMetadata` record and its reader), `raw` (LibRaw decoding), `settings` (options, a
calibration and EXIF made into `optics.CameraSettings`) and `camera_file` (the camera JSON).
"""

from .camera_file import CameraFile, settings_for_shots
from .decode import ENCODINGS, check_photo_content, read_photo, save_photo
from .metadata import RAW_SUFFIXES, PhotoMetadata, RawReadError, read_metadata
from .raw import read_raw, read_raw_stack
from .settings import (
    compression_warning,
    describe_settings,
    metadata_sensor,
    metadata_settings,
    resolve_known,
    resolve_settings,
)

__all__ = [
    "ENCODINGS",
    "RAW_SUFFIXES",
    "CameraFile",
    "PhotoMetadata",
    "RawReadError",
    "check_photo_content",
    "compression_warning",
    "describe_settings",
    "metadata_sensor",
    "metadata_settings",
    "read_metadata",
    "read_photo",
    "read_raw",
    "read_raw_stack",
    "resolve_known",
    "resolve_settings",
    "save_photo",
    "settings_for_shots",
]
