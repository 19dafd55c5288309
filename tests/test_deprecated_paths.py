"""Old import paths keep working for one release, with a DeprecationWarning naming the new home."""

from __future__ import annotations

import importlib

import pytest

#: old module -> (a name it held, the module that holds it now, its name there)
MOVED = {
    "models.blur": ("predict_depth", "models.depth_from_photos.resolution",
                    "run_at_working_resolution"),
    "models.sweep": ("SweepDepth", "models.depth_from_photos.sweep", "SweepDepth"),
    "models.semi_global": ("semi_global_cost", "models.depth_from_photos.semi_global",
                           "semi_global_cost"),
    "models.smoothing": ("edge_aware_smooth", "models.depth_from_photos.smoothing",
                         "edge_aware_smooth"),
    "models.tiling": ("apply_in_tiles", "models.depth_from_photos.tiling", "apply_in_tiles"),
    "optics.settings": ("CameraSettings", "optics.camera", "CameraSettings"),
}


@pytest.mark.parametrize("old", sorted(MOVED))
def test_an_old_path_warns_and_gives_the_same_object(old):
    name, new, new_name = MOVED[old]
    module = importlib.import_module(old)
    with pytest.warns(DeprecationWarning, match=new):
        found = getattr(module, name)
    assert found is getattr(importlib.import_module(new), new_name)


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no_such_name"):
        importlib.import_module("models.blur").no_such_name  # noqa: B018
    with pytest.raises(AttributeError):
        importlib.import_module("models.blur")._box  # private names did not move  # noqa: B018
