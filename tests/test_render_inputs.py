"""The rendering API (`render_focal_stack`, `Camera.render`, `render_defocus`, `ThinLens`,
`Sensor`) given unusual and bad inputs: batch broadcasting, empty images, devices, memory
layouts and the gradients of broadcast inputs."""

import pytest
import torch
from torch.autograd import gradcheck

from optics import (
    Camera,
    CameraSettings,
    Disk,
    Sensor,
    ThinLens,
    render_defocus,
    render_focal_stack,
)

MODES = ["scatter", "gather", "layered"]


def _scene(batch=2, seed=0, dtype=torch.float32):
    gen = torch.Generator().manual_seed(seed)
    image = torch.rand(batch, 3, 8, 9, generator=gen, dtype=dtype)
    depth = torch.rand(batch, 1, 8, 9, generator=gen, dtype=dtype) * 3 + 1
    return image, depth


SETTINGS = CameraSettings(0.05, 2.0, [1.5, 4.0], 150e-6)
#: A PSF of bounded support: a render does not depend on the other renders of its batch (with
#: the Gaussian, the window, and so each PSF's truncated tail, follows the batch's largest CoC).
DISK_SETTINGS = SETTINGS.replace(aperture="disk")


# ------------------------------------------------------------------ batch broadcasting


@pytest.mark.parametrize("mode", MODES)
def test_focal_stack_broadcasts_a_batch_1_depth_as_camera_render_does(mode):
    image, depth = _scene()
    depth = depth[:1]
    stack = render_focal_stack(image, depth, SETTINGS, mode=mode)
    assert stack.shape == (2, 2, 3, 8, 9)
    expected = render_focal_stack(image, depth.expand(2, -1, -1, -1), SETTINGS, mode=mode)
    torch.testing.assert_close(stack, expected, rtol=0, atol=0)
    stack = render_focal_stack(image, depth, DISK_SETTINGS, mode=mode)
    for shot in range(2):  # the same as each shot's camera, which broadcasts the depth too
        expected = DISK_SETTINGS.shot(shot).render(image, depth, mode=mode)
        torch.testing.assert_close(stack[:, shot], expected)


def test_focal_stack_broadcasts_settings_of_batch_1():
    image, depth = _scene()
    stack = render_focal_stack(image, depth, SETTINGS.batched(1))
    torch.testing.assert_close(stack, render_focal_stack(image, depth, SETTINGS), rtol=0, atol=0)


@pytest.mark.parametrize(
    "image_batch, depth_batch, settings, match",
    [
        (2, 3, SETTINGS, r"depth must have shape \(2 or 1, 1, 8, 9\) to match image "
                         r"\(2, 3, 8, 9\), got \(3, 1, 8, 9\)"),
        (1, 2, SETTINGS, r"depth must have shape \(1, 1, 8, 9\) to match image \(1, 3, 8, 9\), "
                         r"got \(2, 1, 8, 9\)"),
        (2, 2, SETTINGS.batched(3), r"settings must have shape \(2,\), \(1, 2\) or \(2, 2\) to "
                                    r"match image \(2, 3, 8, 9\), got \(3, 2\)"),
    ],
)
def test_focal_stack_refuses_what_cannot_broadcast_naming_both_shapes(image_batch, depth_batch,
                                                                      settings, match):
    image, _ = _scene(image_batch)
    _, depth = _scene(depth_batch)
    with pytest.raises(ValueError, match=match):
        render_focal_stack(image, depth, settings)


def test_focal_stack_names_an_invalid_depth_as_it_was_given():
    """Not the depth repeated once per shot: its shape and count are the user's."""
    image, depth = _scene()
    depth[1, 0, 2, 3] = float("nan")
    with pytest.raises(ValueError, match=r"depth must be > 0 .*shape \(2, 1, 8, 9\).*NaN count 1"):
        render_focal_stack(image, depth, SETTINGS)


@pytest.mark.parametrize("where", ["lens", "sensor"])
def test_camera_values_of_another_batch_are_named_not_a_broadcasting_error(where):
    image, depth = _scene()
    three = torch.tensor([1.0, 1.0, 1.0])
    lens = ThinLens(0.05 * three if where == "lens" else 0.05, 2.0, 2.0)
    sensor = Sensor(150e-6 * three if where == "sensor" else 150e-6)
    name = "ThinLens.focal_length" if where == "lens" else "Sensor.pixel_pitch"
    camera = Camera(lens, sensor)
    message = rf"{name} has 3 values .* image \(2, 3, 8, 9\): give one value, or 2"
    with pytest.raises(ValueError, match=message):
        camera.render(image, depth)
    with pytest.raises(ValueError, match=rf"{name} has 3 values .* \(2, 1, 8, 9\)"):
        camera.coc_px(depth)


def test_camera_values_of_batch_2_against_one_image_are_named():
    """Not a complaint about a `coc_px` the user never passed."""
    camera = Camera(ThinLens([0.05, 0.04], 2.0, 2.0), Sensor(150e-6))
    image, depth = _scene(1)
    with pytest.raises(ValueError, match=r"ThinLens.focal_length has 2 values .* image "
                                         r"\(1, 3, 8, 9\): give one value$"):
        camera.render(image, depth)


def test_sensor_values_of_two_batch_sizes_are_refused_when_built():
    with pytest.raises(ValueError, match=r"pixel_pitch and downsample .* sizes"):
        Sensor(torch.full((3,), 5e-6), downsample=torch.tensor([1.0, 2.0]))


def test_batched_camera_values_broadcast_a_batch_1_depth():
    image, depth = _scene()
    camera = Camera(ThinLens([0.05, 0.04], 2.0, [1.5, 3.0]), Sensor([150e-6, 100e-6]), Disk())
    out = camera.render(image, depth[:1])
    torch.testing.assert_close(out, camera.render(image, depth[:1].expand(2, -1, -1, -1)))
    for i in range(2):
        one = Camera(ThinLens(camera.lens.focal_length[i], 2.0, camera.lens.focus_distance[i]),
                     Sensor(camera.sensor.pixel_pitch[i]), Disk())
        torch.testing.assert_close(out[i:i + 1], one.render(image[i:i + 1], depth[:1]))


# ------------------------------------------------------------------ empty images and devices


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("shape", [(2, 3, 0, 9), (2, 3, 8, 0), (0, 3, 8, 9), (2, 0, 8, 9)])
def test_empty_images_render_as_empty_images(mode, shape):
    image = torch.rand(shape)
    depth = torch.full((shape[0], 1, *shape[2:]), 2.0)
    out = Camera(ThinLens(0.05, 2.0, 3.0), Sensor(150e-6)).render(image, depth, mode=mode)
    assert out.shape == shape
    stack = render_focal_stack(image, depth, SETTINGS, mode=mode)
    assert stack.shape == (shape[0], 2, *shape[1:])


def test_a_map_on_another_device_than_the_image_is_named():
    image, depth = _scene()
    with pytest.raises(ValueError, match="coc_px is on meta but image on cpu"):
        render_defocus(image, depth.to("meta"))
    with pytest.raises(ValueError, match="depth is on meta but image on cpu"):
        SETTINGS.shot(0).render(image, depth.to("meta"))
    with pytest.raises(ValueError, match="depth is on meta but image on cpu"):
        render_focal_stack(image, depth.to("meta"), SETTINGS)


# ------------------------------------------------------------------ memory layouts


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("psf", [None, Disk()])
def test_channels_last_and_strided_inputs_render_as_contiguous_ones(mode, psf):
    image, depth = _scene()
    image.requires_grad_()
    coc = depth * 2 - 1
    weights = torch.rand_like(image)
    out = render_defocus(image, coc, psf, mode, depth=depth)
    (grad,) = torch.autograd.grad((out * weights).sum(), image)
    wide = torch.rand(2, 3, 8, 18)
    layouts = [
        (image.contiguous(memory_format=torch.channels_last), coc.transpose(2, 3).contiguous()
         .transpose(2, 3)),
        (image, coc.expand(2, 1, 8, 9).contiguous(memory_format=torch.channels_last)),
    ]
    for other_image, other_coc in layouts:
        other = render_defocus(other_image, other_coc, psf, mode, depth=depth)
        (other_grad,) = torch.autograd.grad((other * weights).sum(), image)
        torch.testing.assert_close(other, out, rtol=1e-6, atol=1e-6)
        torch.testing.assert_close(other_grad, grad, rtol=1e-6, atol=1e-6)
    strided = render_defocus(wide[..., ::2], coc, psf, mode, depth=depth)
    torch.testing.assert_close(strided, render_defocus(wide[..., ::2].contiguous(), coc, psf, mode,
                                                       depth=depth))


# ------------------------------------------------------------------ gradients of broadcast inputs


@pytest.mark.parametrize("mode", MODES)
def test_gradcheck_focal_stack_with_a_batch_1_depth_and_settings(mode):
    image, depth = _scene(2, seed=1, dtype=torch.float64)
    image, depth = image[..., :5, :6].requires_grad_(), depth[:1, :, :5, :6].requires_grad_()
    values = [torch.tensor(v, dtype=torch.float64, requires_grad=True)
              for v in ([[0.05]], [[2.0]], [[1.2, 2.6]], [[3e-4]])]

    def render(image, depth, *values):
        return render_focal_stack(image, depth, CameraSettings(*values), mode=mode, n_layers=3)

    assert gradcheck(render, (image, depth, *values), fast_mode=True)
