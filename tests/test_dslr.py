"""`datasets.DSLR` reads the DFD-indoor release as it is: a fixture in its layout, and the real
folder (`../shared/data/real/dfd_indoor`, skipped where absent)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from test_datasets_fixtures import DSLR_TIMES, write_dslr_release

from datasets import DSLR
from datasets.calibration import depth_pairs
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


# ---- a release rendered with a known camera: calibration and the example run on it -----------

RENDER_PITCH = 4e-5  # metres: CoC at infinity about 6.6 px at f/2.8 (35 mm, focus 1.7 m)
BAND_DEPTHS_M = (0.8, 1.0, 1.3, 1.7, 2.4, 3.5, 6.0)


def write_rendered_release(root: Path, scenes: int = 7, h: int = 96, w: int = 144,
                           split: str = "train") -> list[str]:
    """The release layout with photos rendered by a known camera: two bands of constant depth
    per scene (of `BAND_DEPTHS_M`; wide, so that little of them mixes with the other's blur),
    the f/8 reference itself rendered (slightly blurred), both photos JPEG-compressed, depth in
    millimetres with the sensor's own stamps."""
    from datetime import datetime, timedelta

    import imageio.v3 as iio
    from kornia.color import linear_rgb_to_rgb

    from optics import Camera, Gaussian, Sensor, ThinLens

    def camera(f_number: float) -> Camera:
        return Camera(ThinLens(0.035, f_number, 1.7), Sensor(RENDER_PITCH), Gaussian(0.5))

    folders = [root / "dfd_dataset_indoor_N2_8" / "rgb" / split,
               root / "dfd_dataset_indoor_N8" / "rgb" / split,
               root / "dfd_dataset_indoor_N2_8" / "depth" / split]
    for folder in folders:
        folder.mkdir(parents=True, exist_ok=True)
    generator = torch.Generator().manual_seed(0)
    start = datetime(2018, 4, 26, 16, 0, 0)
    stamps = []
    for i in range(scenes):
        texture = torch.rand(1, 3, h // 3, w // 3, generator=generator, dtype=torch.float64)
        sharp = torch.nn.functional.interpolate(texture, size=(h, w), mode="bicubic",
                                                align_corners=False).clamp(0, 1)
        n = len(BAND_DEPTHS_M)
        halves = (BAND_DEPTHS_M[i % n], BAND_DEPTHS_M[(i + n // 2) % n])
        depth = torch.tensor([halves[2 * r // h] for r in range(h)], dtype=torch.float64)
        depth = depth[:, None].expand(h, w)[None, None].contiguous()
        stamp = (start + timedelta(seconds=40 * i)).isoformat()
        for folder, f_number in ((folders[0], 2.8), (folders[1], 8.0)):
            # the photos are sRGB-encoded JPEGs: encode the linear render
            photo = linear_rgb_to_rgb(camera(f_number).render(sharp, depth)[0].clamp(0, 1))
            iio.imwrite(folder / f"{stamp}.JPG",
                        (photo.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8),
                        extension=".jpg", quality=90)
        depth_stamp = (start + timedelta(seconds=40 * i + 0.7)).isoformat()
        iio.imwrite(folders[2] / f"{depth_stamp}.png",
                    (depth[0, 0].numpy() * 1000).round().astype(np.uint16))
        stamps.append(stamp)
    return stamps


def test_scenes_select_by_time_order(tmp_path):
    write_dslr_release(tmp_path)
    dataset = DSLR(tmp_path, scenes=slice(1, None))
    assert dataset.ids == sorted(DSLR_TIMES)[1:] and len(dataset) == 2
    assert DSLR(tmp_path, scenes=[2]).ids == [sorted(DSLR_TIMES)[2]]
    with pytest.raises(ValueError, match="scenes must be indices among the 3 scenes"):
        DSLR(tmp_path, scenes=[5])


@pytest.mark.slow
def test_calibrate_command_recovers_the_rendering_camera(tmp_path):
    from defocus.cli import main

    write_rendered_release(tmp_path / "data")
    out = tmp_path / "fit" / "camera.json"
    assert main(["calibrate", "--data", "dslr", "--root", str(tmp_path / "data"),
                 "--psf", "gaussian", "--out", str(out)]) == 0
    settings, extra = CameraSettings.read_json(out)
    assert float(settings.focus_distance[0]) == pytest.approx(1.7, rel=0.05)
    assert float(settings.pixel_pitch[0]) == pytest.approx(RENDER_PITCH, rel=0.05)
    # JPEG and the rows where the two bands' blurs mix read as a floor of about a pixel
    assert extra["reference_f_number"] == 8.0 and extra["focus_floor_px"] < 1.5
    assert out.with_suffix(".png").is_file()
    # the loader takes the fitted camera
    assert DSLR(tmp_path / "data", camera=out)[0]["camera"] == settings.to(torch.float32)


def test_calibrate_command_errors(tmp_path, capsys):
    from defocus.cli import main

    assert main(["calibrate", "--out", str(tmp_path / "x.json")]) != 0
    assert "give either --pair" in capsys.readouterr().err
    write_dslr_release(tmp_path / "data")
    assert main(["calibrate", "--data", "dslr", "--root", str(tmp_path / "data"),
                 "--scenes", "7:9"]) != 0
    assert "--scenes '7:9' selects none of the 3 samples" in capsys.readouterr().err
    assert main(["calibrate", "--data", "synthetic", "--root", str(tmp_path)]) != 0
    assert "--data must be a dataset of real photos" in capsys.readouterr().err


def test_relative_samples_model_the_reference_blur(tmp_path):
    """`relative=True`: the f-number of the blur from the f/8 photo to the f/2.8 one (Gaussian
    sigmas add in quadrature) and the image blurred by the fitted floor."""
    write_dslr_release(tmp_path / "data")
    CameraSettings(0.035, 2.8, [1.7], 6e-5, "gaussian:0.5").to_json(
        tmp_path / "cam.json", reference_f_number=8.0, focus_floor_px=1.5)
    plain = DSLR(tmp_path / "data", camera=tmp_path / "cam.json")[0]
    # register=False: the photos as loaded (the registration is checked below)
    relative = DSLR(tmp_path / "data", camera=tmp_path / "cam.json", relative=True,
                    register=False)[0]
    n_eff = float(relative["camera"].f_number[0])
    # CoC scales as 1 / N: the relative blur's CoC squared is the difference of the two shots'
    assert (1 / n_eff) ** 2 == pytest.approx((1 / 2.8) ** 2 - (1 / 8.0) ** 2, rel=1e-5)
    assert torch.equal(relative["focused"], plain["focused"])
    assert relative["image"].std() < plain["image"].std()  # softened by the floor
    torch.testing.assert_close(relative["image"].mean(), plain["image"].mean(), atol=5e-3, rtol=0)


def test_train_command_reads_the_release_at_its_photos_size(tmp_path, capsys):
    """`defocus train --data dslr --root DIR`, as documented: one focused photo per scene
    (n_focus follows the data) at the photos' own size, not a 48x48 resize."""
    import yaml

    from defocus.cli import main

    write_rendered_release(tmp_path / "release", scenes=3, h=40, w=60)
    out = tmp_path / "run"
    assert main(["train", "--data", "dslr", "--root", str(tmp_path / "release"),
                 "--set", "steps=1", "batch_size=1", "width=4", "--out", str(out),
                 "--quiet"]) == 0, capsys.readouterr().err
    assert yaml.safe_load((out / "config.yaml").read_text())["n_focus"] == 1
    from datasets.registry import build_dataset

    data = build_dataset("dslr", tmp_path / "release", size=None)
    assert tuple(data[0]["image"].shape[-2:]) == (40, 60)


def test_relative_samples_are_registered_by_default(tmp_path):
    """`relative=True` registers the f/2.8 photo onto the f/8 one (`register_focused`), as the
    calibration and `estimate_depth` do; `register=False` leaves it as loaded."""
    from datasets.pairs import register_focused

    write_dslr_release(tmp_path / "data")
    CameraSettings(0.035, 2.8, [1.7], 6e-5, "gaussian:0.5").to_json(
        tmp_path / "cam.json", reference_f_number=8.0)
    dataset = DSLR(tmp_path / "data", camera=tmp_path / "cam.json", relative=True)
    assert dataset.register and not DSLR(tmp_path / "data").register
    plain = DSLR(tmp_path / "data", camera=tmp_path / "cam.json")[0]
    expected = register_focused(plain)
    torch.testing.assert_close(dataset[0]["focused"], expected["focused"])


def test_train_step_benchmark_runs_on_the_release(tmp_path, capsys, load_script):
    """`benchmarks/train_step.py` on the release layout: its table, goals and JSON (two
    settings, the profile), so that the benchmark does not rot between GPU sessions."""
    import json

    write_rendered_release(tmp_path / "release", scenes=3, h=40, w=60)
    bench = load_script("benchmarks/train_step.py")
    out = tmp_path / "bench.json"
    code = bench.main(["--dataset", "dslr", "--root", str(tmp_path / "release"),
                       "--scenes", "2", "--workers", "0,1", "--steps", "2", "--warmup", "1",
                       "--repeats", "1", "--crop", "32", "--batch-size", "2", "--no-memory",
                       "--profile", "--json", str(out)])
    assert code == 0
    printed = capsys.readouterr().out
    assert "| small | float32 | off | 0 |" in printed and "| data |" in printed
    results = json.loads(out.read_text())
    assert [row["workers"] for row in results["rows"]] == [0, 1]
    assert all(row["steps_per_s"] > 0 and 0 <= row["data_share"] <= 1 for row in results["rows"])


def test_dslr_causes_prints_the_side_cues_of_a_release(tmp_path, capsys):
    """`examples/dslr_causes.py`'s side-cue table on a release rendered by a thin lens with one
    focus for every colour: both sides binned, and no colour cue."""
    import importlib.util

    write_rendered_release(tmp_path, scenes=7)
    path = Path(__file__).resolve().parents[1] / "examples" / "dslr_causes.py"
    spec = importlib.util.spec_from_file_location("dslr_causes_example", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    example.print_side_cues(depth_pairs(DSLR(tmp_path)), 1.7)
    printed = capsys.readouterr().out
    assert "cues to the side of the focus plane (1.70 m), 7 training scenes" in printed
    assert " front " in printed and " behind " in printed
    rows = [line.split() for line in printed.splitlines()
            if line.split()[1:2] in (["front"], ["behind"])]
    assert {r[1] for r in rows} == {"front", "behind"}
    assert all(abs(float(r[6])) < 0.25 for r in rows)  # red minus blue blur, pixels
    # each scene has one band per side, at different blurs: no scene to compare
    assert "colour spread px: no scene measures both sides" in printed


def test_calibrate_dataset_takes_pairs_aligned_once(tmp_path, monkeypatch):
    from datasets import calibration

    write_rendered_release(tmp_path, scenes=4)
    data = DSLR(tmp_path)
    pairs = depth_pairs(data, [0, 2])

    def aligned_again(*args, **kwargs):
        raise AssertionError("the pairs were aligned again")

    monkeypatch.setattr(calibration, "depth_pairs", aligned_again)
    given = calibration.calibrate_dataset(data, [0, 2], aperture="disk", pairs=pairs).settings
    monkeypatch.setattr(calibration, "depth_pairs", lambda *args, **kwargs: pairs)
    assert given == calibration.calibrate_dataset(data, [0, 2], aperture="disk").settings
    with pytest.raises(ValueError, match=r"one pair per sample of indices \(2\), got 1"):
        calibration.calibrate_dataset(data, [0, 2], pairs=pairs[:1])


def test_synthesized_focus_renders_two_planes_from_the_f8_photo(tmp_path):
    """`focus="synthesized"`: the f/8 photo is the all-in-focus image, two focused images are
    rendered from it and the depth at 0.2 and 0.8 of the 10 m cap with the preset's lens (the
    full-frame pitch scaled to the photos' width); the f/2.8 photo is not read."""
    from optics import render_focal_stack

    written = write_dslr_release(tmp_path)
    data = DSLR(tmp_path, focus="synthesized")
    real = DSLR(tmp_path)[0]
    wide, _, _ = data.files[0]
    wide.write_bytes(b"not a photo any more")  # never read in this mode
    sample = data[0]
    camera = sample["camera"]
    assert camera.focus_distance.tolist() == pytest.approx([2.0, 8.0])
    assert camera.f_number.tolist() == pytest.approx([2.8, 2.8])
    assert camera.focal_length.tolist() == pytest.approx([0.035, 0.035])
    assert camera.pixel_pitch.tolist() == pytest.approx([4.88e-6 * 7360 / 16] * 2)
    assert torch.equal(sample["image"], real["image"])  # the f/8 photo
    assert torch.equal(sample["mask"], real["mask"]) and torch.equal(sample["depth"],
                                                                     real["depth"])
    expected = render_focal_stack(sample["image"][None], sample["depth"][None], camera)[0]
    torch.testing.assert_close(sample["focused"], expected.clamp(0, 1))
    assert len(written) == len(data)


def test_synthesized_focus_takes_the_lens_of_a_camera_json(tmp_path):
    write_dslr_release(tmp_path / "data")
    CameraSettings(0.035, 3.2, [1.9], 6e-5).to_json(tmp_path / "cam.json", focus_floor_px=0.9)
    camera = DSLR(tmp_path / "data", camera=tmp_path / "cam.json",
                  focus="synthesized")[0]["camera"]
    assert camera.f_number.tolist() == pytest.approx([3.2, 3.2])
    assert camera.pixel_pitch.tolist() == pytest.approx([6e-5, 6e-5])
    assert camera.focus_distance.tolist() == pytest.approx([2.0, 8.0])
    with pytest.raises(ValueError, match="relative=True applies to the real f/2.8 photos"):
        DSLR(tmp_path / "data", relative=True, focus="synthesized")
    with pytest.raises(ValueError, match="focus"):
        DSLR(tmp_path / "data", focus="rendered")


def test_synthesized_focus_at_one_plane(tmp_path):
    """`focus_fractions`: one focus plane (the real pairs' situation) at 0.3 of the 10 m cap,
    rendered through that camera; fractions outside (0, 1] or none are refused at the door."""
    from datasets.io import ArgumentError
    from optics import render_focal_stack

    write_dslr_release(tmp_path)
    sample = DSLR(tmp_path, focus="synthesized", focus_fractions=[0.3])[0]
    assert sample["camera"].focus_distance.tolist() == pytest.approx([3.0])
    expected = render_focal_stack(sample["image"][None], sample["depth"][None],
                                  sample["camera"])[0]
    torch.testing.assert_close(sample["focused"], expected.clamp(0, 1))
    for bad in ([], [0.0], [0.2, 1.5], "0.2"):
        with pytest.raises(ArgumentError, match="focus_fractions must be a list of fractions"):
            DSLR(tmp_path, focus="synthesized", focus_fractions=bad)


def test_train_command_focus_option_reaches_the_loader(tmp_path):
    """`defocus train --data dslr --focus synthesized` builds the synthesised DSLR set."""
    from defocus.cli import build_parser
    from defocus.options import dataset_from_options

    write_dslr_release(tmp_path)
    args = build_parser().parse_args(["train", "--data", "dslr", "--root", str(tmp_path),
                                      "--focus", "synthesized"])
    data = dataset_from_options(args)
    assert data.focus == "synthesized" and data[0]["focused"].shape[0] == 2
    args = build_parser().parse_args(["train", "--data", "dslr", "--root", str(tmp_path)])
    assert dataset_from_options(args).focus == "real"
