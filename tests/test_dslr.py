"""`datasets.DSLR` reads the DFD-indoor release as it is: a fixture in its layout, and the real
folder (`../shared/data/real/dfd_indoor`, skipped where absent)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from test_datasets_fixtures import DSLR_TIMES, write_dslr_release

from datasets import DSLR
from datasets.dslr import pair_files
from optics import CameraSettings

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real" / "dfd_indoor"


def srgb_to_linear(array: np.ndarray) -> torch.Tensor:
    x = torch.from_numpy(array.astype(np.float64) / 255).permute(2, 0, 1)
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def test_release_layout_pairs_depth_by_time(tmp_path):
    written = write_dslr_release(tmp_path)
    dataset = DSLR(tmp_path, "train")
    assert dataset.ids == sorted(written)
    depth_dir = tmp_path / "dfd_dataset_indoor_N2_8" / "depth" / "train"
    assert [d.name for _, _, d in dataset.files] == [written[k]["depth_file"] for k in dataset.ids]
    # sorted by position the lists would not pair like this
    assert [d.name for _, _, d in dataset.files] != sorted(p.name for p in depth_dir.iterdir())[:3]
    for k, stamp in enumerate(dataset.ids):
        sample = dataset[k]
        mm = torch.from_numpy(written[stamp]["depth_mm"].astype(np.float64))
        assert torch.equal(sample["mask"][0], mm > 0)
        torch.testing.assert_close(sample["depth"][0][mm > 0], (mm[mm > 0] / 1000).float())
        torch.testing.assert_close(sample["image"], srgb_to_linear(written[stamp]["ref"]).float())
        torch.testing.assert_close(sample["focused"][0],
                                   srgb_to_linear(written[stamp]["wide"]).float())
        torch.testing.assert_close(sample["camera"].pixel_pitch, torch.tensor([4.88e-6 * 7360 / 16]))
    assert dataset.reference_f_number == 8.0


def test_release_depth_too_far_in_time_names_the_photo(tmp_path):
    write_dslr_release(tmp_path, depth_lag_s=(0.9, -0.3, 30.0))
    with pytest.raises(FileNotFoundError, match=f"{DSLR_TIMES[2]}.JPG' has no depth file "
                                                r"within 10 s"):
        DSLR(tmp_path)
    assert len(DSLR(tmp_path, max_gap_s=40.0)) == 3


def test_release_missing_reference_photo_is_named(tmp_path):
    write_dslr_release(tmp_path)
    (tmp_path / "dfd_dataset_indoor_N8" / "rgb" / "train" / f"{DSLR_TIMES[1]}.JPG").unlink()
    with pytest.raises(FileNotFoundError, match="both pair with the f/8 photo"):
        DSLR(tmp_path)


def test_pair_files_refuses_shared_depth():
    photos = [Path("2018-01-01T10:00:00.JPG"), Path("2018-01-01T10:00:01.JPG")]
    with pytest.raises(FileNotFoundError, match="both pair with the depth file"):
        pair_files(photos, [Path("2018-01-01T10:00:00.6.png")], "depth file", 5.0)


def test_camera_json_replaces_the_preset(tmp_path):
    write_dslr_release(tmp_path / "data")
    CameraSettings(0.035, 2.8, [1.9], 6e-5, "disk").to_json(tmp_path / "cam.json",
                                                           reference_f_number=9.5)
    dataset = DSLR(tmp_path / "data", camera=tmp_path / "cam.json")
    camera = dataset[0]["camera"]
    assert camera.aperture == "disk" and float(camera.focus_distance) == pytest.approx(1.9)
    assert dataset.reference_f_number == 9.5


@pytest.mark.skipif(not REAL.is_dir(), reason="../shared/data/real/dfd_indoor is absent")
def test_real_release_folder():
    dataset = DSLR(REAL, "train")
    assert len(dataset) == 81
    for _, _, depth in dataset.files:
        assert depth.suffix == ".png"
    sample = dataset[len(dataset) - 1]
    assert sample["image"].shape == (3, 432, 645) and sample["focused"].shape == (1, 3, 432, 645)
    depth = sample["depth"][sample["mask"]]
    assert 0.5 < float(depth.median()) < 8.0  # metres, not millimetres
    torch.testing.assert_close(sample["camera"].pixel_pitch,
                               torch.tensor([4.88e-6 * 7360 / 645]))
