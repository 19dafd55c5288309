"""Deprecated: moved to `models.depth_from_photos.semi_global`.

The old import path `models.semi_global` keeps working for one release with a `DeprecationWarning`.
"""

from .deprecation import moved_names

__getattr__ = moved_names(__name__, ['models.depth_from_photos.semi_global'])
