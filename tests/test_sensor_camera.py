import pytest
import torch
from torch import nn

from optics import Camera, CameraSettings, Disk, Gaussian, Sensor, ThinLens


def test_sensor_pixels_roundtrip(dtype):
    sensor = Sensor(5.6e-6, downsample=4)
    length = torch.tensor([0.0, 22.4e-6, 1e-3], dtype=dtype)
    px = sensor.to_pixels(length)
    torch.testing.assert_close(px, torch.tensor([0.0, 1.0, 1e-3 / 22.4e-6], dtype=dtype))
    torch.testing.assert_close(sensor.to_metres(px), length)
    assert px.dtype == dtype


def test_sensor_batched_pitch():
    sensor = Sensor(torch.tensor([5e-6, 10e-6]))
    px = sensor.to_pixels(torch.full((2, 1, 2, 2), 20e-6, dtype=torch.float64))
    torch.testing.assert_close(px[:, 0, 0, 0], torch.tensor([4.0, 2.0], dtype=torch.float64))


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"pixel_pitch": 0.0}, "pixel_pitch"),
        ({"pixel_pitch": -5e-6}, "pixel_pitch"),
        ({"pixel_pitch": float("inf")}, "pixel_pitch"),
        ({"pixel_pitch": 5e-6, "downsample": 0}, "downsample"),
        ({"pixel_pitch": 5e-6, "resolution": (0, 10)}, "resolution"),
    ],
)
def test_bad_sensor(kwargs, name):
    with pytest.raises(ValueError, match=name):
        Sensor(**kwargs)


def make_camera(**overrides):
    values = {"focal_length": 0.035, "f_number": 2.8, "focus_distance": 2.0, "pixel_pitch": 22.4e-6}
    values.update(overrides)
    lens = ThinLens(values["focal_length"], values["f_number"], values["focus_distance"])
    return Camera(lens, Sensor(values["pixel_pitch"]))


def test_coc_px_closed_form(dtype):
    camera = make_camera()
    depth = torch.tensor([[[[1.0, 4.0]]]], dtype=dtype)
    f, n, focus, pitch = 0.035, 2.8, 2.0, 22.4e-6
    expected = [f * f * abs(d - focus) / (n * d * (focus - f)) / pitch for d in (1.0, 4.0)]
    torch.testing.assert_close(camera.coc_px(depth).flatten(), torch.tensor(expected, dtype=dtype))
    torch.testing.assert_close(
        camera.signed_coc_px(depth).flatten(),
        torch.tensor([-expected[0], expected[1]], dtype=dtype),
    )


@pytest.mark.parametrize("name", ["focal_length", "f_number", "focus_distance", "pixel_pitch"])
def test_gradcheck_coc_px_every_parameter(name):
    def fn(value, depth):
        return make_camera(**{name: value}).coc_px(depth)

    base = getattr(make_camera().settings(), name).detach().double()
    value = base.clone().requires_grad_(True)
    depth = torch.tensor([[[[0.8, 1.5], [3.0, 7.0]]]], dtype=torch.float64, requires_grad=True)
    # Finite-difference step relative to the value: pixel pitches are ~1e-5 m.
    assert torch.autograd.gradcheck(fn, (value, depth), eps=1e-6 * float(base))


def test_camera_settings_roundtrip():
    camera = make_camera()
    again = camera.settings().shot(0)
    depth = torch.rand(1, 1, 3, 3) + 1.0
    torch.testing.assert_close(again.coc_px(depth).float(), camera.coc_px(depth))
    with pytest.raises(ValueError, match="focus_distance"):
        CameraSettings.from_dict({"focal_length": 0.05, "f_number": 2.0, "pixel_pitch": 5e-6})


def test_camera_is_a_module_with_parameters():
    lens = ThinLens(0.05, nn.Parameter(torch.tensor(2.0)), 2.0)
    camera = Camera(lens, Sensor(5e-6), Gaussian(nn.Parameter(torch.tensor(0.5))))
    assert {n for n, _ in camera.named_parameters()} == {"lens.f_number", "aperture.scale"}
    assert "sensor.pixel_pitch" in camera.state_dict()


def test_camera_type_errors():
    with pytest.raises(TypeError, match="lens"):
        Camera("lens", Sensor(5e-6))
    with pytest.raises(TypeError, match="aperture"):
        Camera(ThinLens(0.05, 2.0, 2.0), Sensor(5e-6), aperture="disk")
    assert isinstance(Camera(ThinLens(0.05, 2.0, 2.0), Sensor(5e-6), Disk()).aperture, Disk)


@pytest.mark.parametrize(
    "image_shape, depth_shape, name",
    [((3, 8, 8), (1, 1, 8, 8), "image"), ((1, 3, 8, 8), (1, 8, 8), "depth|coc_px")],
)
def test_render_rejects_wrong_rank(image_shape, depth_shape, name):
    camera = make_camera()
    with pytest.raises(ValueError, match=name):
        camera.render(torch.rand(image_shape), torch.full(depth_shape, 3.0))


@pytest.mark.parametrize("bad", [0.0, -2.0, float("nan")])
def test_render_rejects_bad_depth(bad):
    depth = torch.full((1, 1, 8, 8), 3.0)
    depth[0, 0, 2, 2] = bad
    with pytest.raises(ValueError, match="depth"):
        make_camera().render(torch.rand(1, 3, 8, 8), depth)


def test_integer_lengths_convert_in_the_pitch_dtype():
    sensor = Sensor(5e-6)
    assert torch.allclose(sensor.to_pixels(torch.tensor([3])).float(), torch.tensor([6e5]))
    assert torch.allclose(sensor.to_metres(torch.tensor([3])).float(), torch.tensor([1.5e-5]))


def test_camera_render_names_the_depth_it_was_given():
    camera = Camera(ThinLens(0.05, 2.0, 2.0), Sensor(1e-5), Disk())
    with pytest.raises(ValueError, match=r"^depth must have shape \(1, 1, 8, 8\) to match image "
                                         r"\(1, 3, 8, 8\), got \(2, 1, 8, 8\)"):
        camera.render(torch.rand(1, 3, 8, 8), torch.full((2, 1, 8, 8), 3.0))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_noise_std_closed_form(dtype):
    """Read noise over the light, shot noise over its square root, at the reference exposure
    the `CaptureNoise` model (read 0.004, shot 0.0004)."""
    from optics import noise_std

    x = torch.tensor([0.0, 0.25, 1.0], dtype=dtype)
    expected = torch.tensor([0.004, (0.004**2 + 0.0001) ** 0.5, (0.004**2 + 0.0004) ** 0.5],
                            dtype=dtype)
    torch.testing.assert_close(noise_std(x, 0.004, 0.0004), expected)
    one_stop_down = torch.tensor([0.008, (0.008**2 + 0.0002) ** 0.5], dtype=dtype)
    torch.testing.assert_close(noise_std(x[:2], 0.004, 0.0004, torch.tensor(0.5, dtype=dtype)),
                               one_stop_down)
    assert noise_std(x, 0.0, 0.0).dtype == dtype


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_relative_light_is_the_aperture_area_ratio(dtype):
    """One stop (a factor sqrt 2 in f-number) halves the light; gradcheck in the f-number."""
    from optics import relative_light

    numbers = torch.tensor([2.8, 2.8 * 2**0.5, 1.4], dtype=dtype)
    torch.testing.assert_close(relative_light(numbers, 2.8),
                               torch.tensor([1.0, 0.5, 4.0], dtype=dtype))
    start = torch.tensor([2.8, 4.0, 8.0], dtype=torch.float64)
    numbers = torch.tensor([2.0, 5.6, 8.0], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda n: relative_light(n, start), (numbers,))


def test_noise_std_gradcheck_and_finite_at_zero():
    from optics import noise_std

    x = torch.tensor([0.1, 0.5, 0.9], dtype=torch.float64, requires_grad=True)
    light = torch.tensor([0.3, 1.0, 2.0], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: noise_std(a, 0.004, 0.0004, b), (x, light))
    black = torch.zeros(2, dtype=torch.float64, requires_grad=True)
    noise_std(black, 0.0, 0.0004).sum().backward()
    assert torch.isfinite(black.grad).all()
