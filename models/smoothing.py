"""Deprecated: moved to `models.depth_from_photos.smoothing`.

The old import path `models.smoothing` keeps working for one release with a `DeprecationWarning`.
"""

from .deprecation import moved_names

__getattr__ = moved_names(__name__, ['models.depth_from_photos.smoothing'])
