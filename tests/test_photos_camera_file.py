"""The camera file (`datasets.photos.CameraFile`): its door names the file and the key of
every value it refuses, and the per-shot rule is the same for every reader."""

from __future__ import annotations

import json
import re

import pytest

from datasets import DSLR, DataFormatError
from datasets.photos import CameraFile, settings_for_shots
from optics import CameraSettings


def _write(path, **values):
    data = {**CameraSettings(0.05, [8.3, 2.0], [1.0, 3.0], 2e-5).to_dict(), **values}
    path.write_text(json.dumps(data))
    return path


def test_a_camera_file_and_its_values(tmp_path):
    path = _write(tmp_path / "cam.json", photos=["near.png", "far.png"], reference_f_number=8,
                  focus_floor_px=1.5, exposure_gain=[1.1, 1.0, 0.9])
    camera = CameraFile.read(path)
    assert camera.photos == ("near.png", "far.png") and camera.reference_f_number == 8.0
    assert camera.focus_floor_px == 1.5 and camera.exposure_gain == (1.1, 1.0, 0.9)
    assert camera.settings.f_number.tolist() == pytest.approx([8.3, 2.0])


def test_a_camera_file_that_is_not_utf8_is_refused_naming_it(tmp_path):
    path = tmp_path / "cam.json"
    path.write_bytes('{"f_number": 2.8, "lens": "Objectif \xe9"}'.encode("latin-1"))
    with pytest.raises(DataFormatError, match=f"{path}'?: expected a camera JSON in UTF-8"):
        CameraFile.read(path)


def test_three_focus_distances_for_two_photos_are_refused_naming_the_key(tmp_path):
    path = tmp_path / "cam.json"
    CameraSettings(0.05, 2.0, [1.0, 2.0, 3.0], 2e-5).to_json(path)
    with pytest.raises(DataFormatError, match=f'{path}: "focus_distance" holds 3 different '
                                              r"values \[1.0, 2.0, 3.0\], one per shot, but "
                                              r"2 photos \(2 shot\(s\)\)"):
        CameraFile.read(path, n_shots=2, shots="2 photos")
    assert CameraFile.read(path, n_shots=2, given=("focus_distance",)).settings.n_shots == 3
    assert CameraFile.read(path).settings.n_shots == 3  # no count given: any


@pytest.mark.parametrize("key, value", [("focus_floor_px", "x"), ("focus_floor_px", -1.0),
                                        ("reference_f_number", 0.5),
                                        ("exposure_gain", [1.0, "x", 1.0]), ("photos", "a.png")])
def test_bad_extra_values_are_refused_naming_the_file_and_key(tmp_path, key, value):
    path = _write(tmp_path / "cam.json", **{key: value})
    with pytest.raises(DataFormatError, match=re.escape(f"{path}: \"{key}\" must ") + ".*, got "
                       + re.escape(repr(value))):
        CameraFile.read(path)


def test_a_loader_refuses_a_focus_floor_that_is_no_number(tmp_path):
    from test_datasets_fixtures import write_dslr_release

    write_dslr_release(tmp_path / "data")
    camera = tmp_path / "cam.json"
    CameraSettings(0.035, 2.8, [1.9], 6e-5).to_json(camera, focus_floor_px="x")
    with pytest.raises(DataFormatError, match=f"{camera}: \"focus_floor_px\" must be a finite "
                                              "number of pixels >= 0, got 'x'"):
        DSLR(tmp_path / "data", camera=camera)


def test_dslr_refuses_a_sensor_width_of_zero_naming_it(tmp_path):
    from test_datasets_fixtures import write_dslr_release

    write_dslr_release(tmp_path / "data")
    with pytest.raises(ValueError, match="sensor_width_px must be > 0 pixels, got 0"):
        DSLR(tmp_path / "data", sensor_width_px=0)


def test_settings_for_shots_follows_the_same_rule():
    assert settings_for_shots(CameraSettings(0.05, [2.8, 2.8], 1.7, 6e-5), 1).n_shots == 1
    with pytest.raises(DataFormatError, match='camera: "f_number" holds 2 different values'):
        settings_for_shots(CameraSettings(0.05, [2.8, 2.0], 1.7, 6e-5), 1)


def test_a_learned_camera_with_a_mask_is_refused_and_one_without_is_read(tmp_path):
    """`defocus train --learn-optics ...` writes camera.json with the learned mask (or null):
    a camera file's PSF is its "aperture" spec, so a mask there would be dropped silently."""
    import torch

    from optics import LearnableCamera

    settings = CameraSettings(0.05, 2.0, [1.5, 4.0], 2e-5, "disk")
    for learn, refused in ((("focus", "f-number", "mask"), True), (("focus",), False)):
        record = LearnableCamera(settings, (0.5, 10.0), learn=learn).record()
        path = tmp_path / f"camera_{len(learn)}.json"
        path.write_text(json.dumps(record))
        if refused:
            with pytest.raises(DataFormatError, match=rf'{re.escape(str(path))}: holds a '
                               r'learned aperture "mask".*defocus evaluate CHECKPOINT'):
                CameraFile.read(path)
        else:
            camera = CameraFile.read(path)
            assert camera.settings.focus_distance.tolist() == pytest.approx(
                torch.tensor(record["focus_distance"]).tolist())
