"""`CameraSettings`, the settings of the F shots of a scene: it lives in `optics.camera` beside
`Camera`, into which its shots convert. This path keeps working for one release with a
`DeprecationWarning`; import it from `optics`.
"""

import warnings as _warnings


def __getattr__(name: str):
    from . import camera

    if name.startswith("_") or not hasattr(camera, name):
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    _warnings.warn(f"optics.settings.{name} moved to optics.camera.{name}; the old path goes in "
                   "the next release", DeprecationWarning, stacklevel=2)
    return getattr(camera, name)
