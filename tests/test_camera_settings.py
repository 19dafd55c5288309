"""CameraSettings: the one type for the F shots of a scene; the PSF spec registry."""

from __future__ import annotations

import pytest
import torch

from optics import (
    CameraSettings,
    Disk,
    Gaussian,
    Mask,
    Polygon,
    aperture_spec,
    collate,
    parse_aperture,
    render_focal_stack,
)


def test_broadcast_shapes_and_shots():
    s = CameraSettings(0.05, [1.4, 2.8], [2.0, 6.0], 180e-6)
    assert s.shape == (2,) and s.n_shots == 2 and not s.is_batched
    torch.testing.assert_close(s.focal_length, torch.tensor([0.05, 0.05], dtype=torch.float64))
    camera = s.shot(1)
    assert float(camera.lens.f_number) == 2.8 and float(camera.lens.focus_distance) == 6.0
    batch = s.batched(3)
    assert batch.shape == (3, 2) and batch[1:].shape == (2, 2) and batch[0].shape == (2,)
    assert batch.camera().lens.focus_distance.shape == (6,)
    assert s.select_shots([1]).focus_distance.tolist() == [6.0]


def test_coc_at_infinity_is_the_thin_lens_limit():
    s = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-5)
    far = torch.full((2, 1, 1, 1), 1e12, dtype=torch.float64)
    expected = s.camera().signed_coc_px(far).flatten()
    torch.testing.assert_close(s.coc_at_infinity_px(), expected)
    torch.testing.assert_close(s.coc_at_infinity_px()[0],
                               torch.tensor(0.05**2 / (2.0 * 1.95 * 1e-5), dtype=torch.float64))


def test_collate_to_and_dataloader():
    samples = [{"camera": CameraSettings(0.05, 2.0, [2.0, d], 1e-5, "disk").to(torch.float32),
                "x": torch.zeros(1)} for d in (5.0, 6.0, 7.0)]
    batch = next(iter(torch.utils.data.DataLoader(samples, batch_size=3, collate_fn=collate)))
    camera = batch["camera"]
    assert isinstance(camera, CameraSettings) and camera.shape == (3, 2)
    assert camera.aperture == "disk" and camera.focus_distance.dtype == torch.float32
    assert camera.focus_distance[:, 1].tolist() == [5.0, 6.0, 7.0]
    assert camera.to(torch.float64).pixel_pitch.dtype == torch.float64
    with pytest.raises(ValueError, match="apertures"):
        collate([CameraSettings(0.05, 2, [2.0], 1e-5, "disk"), CameraSettings(0.05, 2, [2.0], 1e-5)])


def test_json_round_trip(tmp_path):
    s = CameraSettings(0.035, [2.0, 4.0], [1.2, 3.0], 4e-6, "polygon:7:0.2")
    s.to_json(tmp_path / "cam.json", note="kept")
    again = CameraSettings.from_json(tmp_path / "cam.json")
    assert again == s and again.aperture == "polygon:7:0.2"
    one = CameraSettings(0.035, 2.0, 3.0, 4e-6)
    assert CameraSettings.from_dict(one.to_dict()) == one
    # files written before the registry used a {"family": ...} object
    old = {"focal_length": 0.05, "f_number": 2.0, "focus_distance": 2.0, "pixel_pitch": 1e-5,
           "psf": {"family": "gaussian", "scale": 0.4}}
    assert CameraSettings.from_dict(old).aperture == "gaussian:0.4"
    # the aperture is written under "aperture"; files of 0.2 wrote it under "psf"
    assert one.to_dict()["aperture"] == one.aperture and "psf" not in one.to_dict()
    assert CameraSettings.from_dict({**old, "psf": "disk"}).aperture == "disk"
    assert CameraSettings.from_dict({**old, "aperture": "polygon:5"}).aperture == "polygon:5"


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"focal_length": -0.05}, "focal_length"),
    ({"f_number": float("nan")}, "f_number"),
    ({"focus_distance": 0.01}, "focus_distance must be > focal_length"),
    ({"focal_length": 50.0}, r"focal_length .*did you give millimetres\? 50 mm is 0\.05 m"),
    ({"pixel_pitch": "5e-6"}, "pixel_pitch must be a number"),
    ({"focus_distance": []}, "F >= 1"),
    ({"focus_distance": [[[2.0]]]}, r"\(F,\) or \(B, F\)"),
    ({"aperture": "hexagon"}, "unknown family"),
    ({"aperture": Disk()}, "spec string"),
])
def test_bad_values_are_refused_by_name(kwargs, match):
    values = {"focal_length": 0.05, "f_number": 2.0, "focus_distance": [2.0, 6.0],
              "pixel_pitch": 1e-5, **kwargs}
    with pytest.raises((ValueError, TypeError), match=match):
        CameraSettings(**values)


def test_render_focal_stack_matches_each_shot():
    g = torch.Generator().manual_seed(0)
    image = torch.rand(2, 3, 12, 12, generator=g, dtype=torch.float64)
    depth = 1.5 + 4 * torch.rand(2, 1, 12, 12, generator=g, dtype=torch.float64)
    s = CameraSettings(0.05, 2.0, [[2.0, 6.0], [3.0, 4.0]], 180e-6, "disk")
    stack = render_focal_stack(image, depth, s)
    assert stack.shape == (2, 2, 3, 12, 12)
    for b in range(2):
        for f in range(2):
            alone = render_focal_stack(image[b:b + 1], depth[b:b + 1], s[b].select_shots([f]))
            torch.testing.assert_close(stack[b, f], alone[0, 0], atol=1e-3, rtol=0)
            direct = s[b].shot(f).render(image[b:b + 1], depth[b:b + 1])
            torch.testing.assert_close(alone[0, 0], direct[0])


def test_gradients_reach_every_setting():
    image = torch.rand(1, 3, 10, 10, dtype=torch.float64)
    depth = torch.full((1, 1, 10, 10), 4.0, dtype=torch.float64)
    depth[..., 5:] = 2.5
    values = {k: torch.tensor([v], dtype=torch.float64, requires_grad=True)
              for k, v in (("focal_length", 0.05), ("f_number", 2.0), ("focus_distance", 3.0),
                           ("pixel_pitch", 1e-4))}
    render_focal_stack(image, depth, CameraSettings(**values)).square().sum().backward()
    for name, value in values.items():
        assert value.grad is not None and bool(torch.isfinite(value.grad).all()), name
        assert float(value.grad.abs()) > 0, name


@pytest.mark.parametrize(("spec", "expected"), [
    ("gaussian", Gaussian(0.5)), ("gaussian:0.25", Gaussian(0.25)), ("disk", Disk()),
    ("polygon:6", Polygon(6)), ("Polygon:5:0.3", Polygon(5, 0.3)),
])
def test_aperture_spec_round_trip(spec, expected):
    aperture = parse_aperture(spec)
    assert type(aperture) is type(expected) and repr(aperture) == repr(expected)
    assert parse_aperture(aperture_spec(aperture)).extra_repr() == aperture.extra_repr()


@pytest.mark.parametrize("spec", ["hexagon", "gaussian:-1", "gaussian:x", "disk:3", "polygon",
                                  "polygon:2", "polygon:6.5", "gaussian:nan"])
def test_bad_aperture_specs_list_what_is_allowed(spec):
    with pytest.raises(ValueError, match="expected one of: gaussian"):
        parse_aperture(spec)


def test_mask_has_no_spec():
    with pytest.raises(ValueError, match="no spec"):
        aperture_spec(Mask(torch.ones(3, 3)))


def test_json_numbers_carry_no_float32_noise(tmp_path):
    """Settings held in float32 are written as the numbers they were given (2.8, not
    2.799999952316284), and read back to the same float32 values."""
    import json

    s = CameraSettings(0.035, [2.8, 8.3], [1.7, 2.2], 4.88e-6).to(torch.float32)
    s.to_json(tmp_path / "cam.json")
    data = json.loads((tmp_path / "cam.json").read_text())
    assert data["f_number"] == [2.8, 8.3] and data["pixel_pitch"] == [4.88e-6, 4.88e-6]
    assert CameraSettings.from_json(tmp_path / "cam.json").to(torch.float32) == s


@pytest.mark.parametrize("focus", [[2.0], [[2.0]], [[2.0, 6.0]], [[2.0], [3.0]]])
def test_json_round_trip_keeps_the_batch_shape(tmp_path, focus):
    s = CameraSettings(0.05, 2.0, focus, 1e-5)
    s.to_json(tmp_path / "cam.json")
    back = CameraSettings.from_json(tmp_path / "cam.json")
    assert back.shape == s.shape and back == s
    assert CameraSettings.from_dict(s.to_dict()) == s


def test_to_json_refuses_extras_that_replace_a_setting_or_are_not_finite(tmp_path):
    s = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-5, "disk")
    path = tmp_path / "cam.json"
    for extra in ({"f_number": 99}, {"psf": "gaussian"}, {"aperture": "gaussian"}):
        with pytest.raises(ValueError, match="must not replace the settings"):
            s.to_json(path, **extra)
    with pytest.raises(ValueError, match=r"finite numbers .*'gain': \[1.0, nan\]"):
        s.to_json(path, gain=[1.0, float("nan")])
    assert not path.exists()
    s.to_json(path, aperture={"family": "disk"}, note="the same aperture, written as an object")
    assert CameraSettings.read_json(path) == (s, {"note": "the same aperture, written as an object"})


def test_to_json_checks_values_changed_in_place(tmp_path):
    s = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-5)
    s.f_number[0] = -1.0
    with pytest.raises(ValueError, match="f_number"):
        s.to_json(tmp_path / "cam.json")
    assert not (tmp_path / "cam.json").exists()


@pytest.mark.parametrize(("near", "far"), [(-1.0, 1.0), (float("nan"), 1.0), (2.0, 1.0), (1.0, 1.0)])
def test_largest_coc_refuses_a_range_that_is_not_increasing(near, far):
    with pytest.raises(ValueError, match="0 < near < far"):
        CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4).largest_coc_px(near, far)


def test_a_miscounted_focus_distance_names_its_source():
    from datasets.photos.metadata import PhotoMetadata
    from datasets.photos.settings import resolve_settings

    stated = {"focal_length": 0.05, "f_number": 2.0}
    photos = [PhotoMetadata("a.jpg", stated), PhotoMetadata("b.jpg", stated)]
    calibration = CameraSettings(0.05, 2.0, [1.0, 2.0, 3.0], 1e-5)
    with pytest.raises(ValueError, match=r"photo \(2\): the calibration holds 3 \(1, 2, 3 m\); "
                                         "no photo's EXIF states it"):
        resolve_settings(photos, {}, calibration)
    with pytest.raises(ValueError, match=r"photo \(2\): --focus-distance holds 3$"):
        resolve_settings(photos, {"pixel_pitch": 1e-5, "focus_distance": [1.0, 2.0, 3.0]})
