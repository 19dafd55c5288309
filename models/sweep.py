"""Deprecated: the sweep now lives in `models.depth_from_photos.sweep`.

The old import path `models.sweep` keeps working for one release with a `DeprecationWarning`.
"""

from .deprecation import moved_names

__getattr__ = moved_names(__name__, ['models.depth_from_photos.sweep',
                          'models.depth_from_photos.confidence',
                          'models.depth_from_photos.photometry',
                          'models.depth_from_photos.fourier_blur',
                          'models.depth_from_photos.thin_lens'])
