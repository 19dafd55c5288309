"""Deprecated: the camera-general network and the thin-lens machinery now live in `models.depth_from_photos`.

The old import path `models.blur` keeps working for one release with a `DeprecationWarning`.
"""

from .deprecation import moved_names

__getattr__ = moved_names(__name__, ['models.depth_from_photos.blur_net',
                          'models.depth_from_photos.thin_lens',
                          'models.depth_from_photos.confidence',
                          'models.depth_from_photos.photometry',
                          'models.depth_from_photos.resolution'], {'predict_depth': 'run_at_working_resolution'})
