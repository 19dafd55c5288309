"""Issue 11, camera values and photos: cases 6, 7, 8 and 12 reproduced, each with its clear error
or its safe behaviour."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from optics import Camera, CameraSettings, Sensor, ThinLens, render_defocus
from optics.checks import check_finite
from optics.focal_stack import render_focal_stack


# ---- case 6: strings and empty tensors --------------------------------------------------------
@pytest.mark.parametrize("position", [0, 1, 2])
def test_case6_string_parameter_refused(position):
    args = [0.05, 2.8, 2.0]
    args[position] = "25"
    with pytest.raises(TypeError, match="string '25'"):
        ThinLens(*args)
    with pytest.raises(TypeError, match="pixel_pitch .*string"):
        Sensor("5.6e-6")
    with pytest.raises(TypeError, match="focus_distance must hold numbers"):
        ThinLens(0.05, 2.8, ["2", "5"])
    with pytest.raises(TypeError, match="focus_distance must be a number"):
        CameraSettings(0.05, 2.8, "25", 5.6e-6)


def test_case6_empty_tensor_refused():
    with pytest.raises(ValueError, match="focal_length must hold at least one value"):
        ThinLens(torch.tensor([]), 2.8, 2.0)
    with pytest.raises(ValueError, match="pixel_pitch must hold at least one value"):
        Sensor(torch.empty(0))


# ---- case 7: parameters checked at every use --------------------------------------------------
def test_case7_parameter_changed_after_construction_is_named_at_use():
    focal = nn.Parameter(torch.tensor(0.05))
    camera = Camera(ThinLens(focal, 2.8, 2.0), Sensor(5.6e-6, downsample=4))
    depth = torch.full((1, 1, 8, 8), 3.0)
    camera.coc_px(depth)  # fine before the step
    with torch.no_grad():
        focal.fill_(-1.0)  # as an optimiser step can
    with pytest.raises(ValueError, match=r"ThinLens\.focal_length must be finite and > 0.*-1"):
        camera.coc_px(depth)
    with pytest.raises(ValueError, match="focal_length"):
        camera.render(torch.rand(1, 3, 8, 8), depth)


def test_case7_pitch_and_focus_checked_at_use():
    pitch = nn.Parameter(torch.tensor(5.6e-6))
    focus = nn.Parameter(torch.tensor(2.0))
    camera = Camera(ThinLens(0.05, 2.8, focus), Sensor(pitch))
    depth = torch.full((1, 1, 4, 4), 3.0)
    with torch.no_grad():
        pitch.fill_(float("nan"))
    with pytest.raises(ValueError, match=r"Sensor\.pixel_pitch must be finite"):
        camera.coc_px(depth)
    with torch.no_grad():
        pitch.fill_(5.6e-6)
        focus.fill_(0.01)  # in front of the focal point
    with pytest.raises(ValueError, match="focus_distance must be greater than focal_length"):
        camera.coc_px(depth)


def test_unit_warnings_for_millimetres():
    with pytest.warns(UserWarning, match="focal_length is 50 m.*did you give millimetres") as w:
        ThinLens(50.0, 2.8, 2000.0)
    assert w[0].filename == __file__  # points at the caller
    with pytest.warns(UserWarning, match="pixel_pitch is 0.0056 m.*did you give millimetres"):
        Sensor(5.6e-3)


def test_plausible_values_do_not_warn(recwarn):
    ThinLens(0.6, 5.6, 100.0)
    Sensor(20e-6, downsample=8)
    assert not [w for w in recwarn if "millimetres" in str(w.message)]


# ---- case 8: half-precision renders give finite gradients -------------------------------------
@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_case8_half_precision_render_gradients_finite(dtype):
    torch.manual_seed(0)
    image = torch.rand(1, 3, 16, 16, dtype=dtype)
    depth = (torch.rand(1, 1, 16, 16) * 5 + 1).to(dtype)
    params = {n: nn.Parameter(torch.tensor(v)) for n, v in
              (("f", 0.035), ("n", 2.8), ("df", 2.0), ("p", 5.6e-6))}
    camera = Camera(ThinLens(params["f"], params["n"], params["df"]),
                    Sensor(params["p"], downsample=4))
    out = camera.render(image, depth)
    assert out.dtype == dtype
    (out.float() * torch.rand(1, 3, 16, 16)).sum().backward()
    for name, p in params.items():  # was NaN for the pitch before
        assert torch.isfinite(p.grad), name
        assert p.grad != 0, name
    # The CoC itself (what the camera contributes) has float32 gradients from a half depth map.
    weight = torch.rand(1, 1, 16, 16)
    grads = []
    for d in (depth, depth.float()):
        for p in params.values():
            p.grad = None
        (camera.coc_px(d) * weight).sum().backward()
        grads.append({n: float(p.grad) for n, p in params.items()})
    for name in params:
        assert grads[0][name] == pytest.approx(grads[1][name], rel=1e-5), name


def test_case8_coc_computed_in_float32_for_half_depth():
    camera = Camera(ThinLens(0.035, 2.8, 2.0), Sensor(5.6e-6, downsample=4))
    depth = torch.tensor([1.0, 8.0])
    coc = camera.coc_px(depth.half())
    assert coc.dtype == torch.float32
    assert torch.allclose(coc, camera.coc_px(depth), rtol=1e-3)


def test_case8_focal_stack_half_precision():
    pitch = nn.Parameter(torch.tensor(22.4e-6))
    settings = CameraSettings(0.035, 2.8, torch.tensor([2.0, 8.0]), pitch)
    stack = render_focal_stack(torch.rand(1, 3, 12, 12).half(),
                               torch.full((1, 1, 12, 12), 4.0).half(), settings)
    assert stack.dtype == torch.float16 and torch.isfinite(stack).all()
    stack.float().sum().backward()
    assert torch.isfinite(pitch.grad).all()


# ---- case 12: a NaN pixel is reported, naming the input --------------------------------------
def test_case12_nan_pixel_named_by_render_defocus():
    image = torch.rand(1, 3, 32, 32)
    image[0, 0, 16, 16] = float("nan")
    with pytest.raises(ValueError, match=r"image has 1 NaN .* at index \(0, 0, 16, 16\)"):
        render_defocus(image, torch.full((1, 1, 32, 32), 6.0))


def test_case12_inf_pixel_named_by_camera_and_focal_stack():
    image = torch.rand(1, 3, 8, 8)
    image[0, 2, 1, 3] = float("inf")
    depth = torch.full((1, 1, 8, 8), 3.0)
    with pytest.raises(ValueError, match=r"image has 0 NaN and 1 infinite"):
        Camera(ThinLens(0.05, 2.0, 2.0), Sensor(2e-5)).render(image, depth)
    settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 2e-5)
    with pytest.raises(ValueError, match=r"image has 0 NaN and 1 infinite.*\(0, 2, 1, 3\)"):
        render_focal_stack(image, depth, settings)


def test_check_finite_passes_finite_and_names_input():
    check_finite("focused", torch.rand(2, 3))
    with pytest.raises(ValueError, match="^focused has 2 NaN"):
        check_finite("focused", torch.tensor([float("nan"), 1.0, float("nan")]))


def test_the_switch_turns_the_tensor_checks_off_and_on_and_keeps_results():
    """`checks_disabled` trusts shapes and tensor values (a hot path); numbers stay checked."""
    import pytest
    import torch

    from optics import Camera, Sensor, ThinLens
    from optics.checks import checks_disabled, set_checks

    camera = Camera(ThinLens(0.05, 2.0, 2.0), Sensor(150e-6))
    image, depth = torch.rand(1, 3, 8, 8), torch.full((1, 1, 8, 8), 3.0)
    checked = camera.render(image, depth)
    with checks_disabled():
        torch.testing.assert_close(camera.render(image, depth), checked, rtol=0, atol=0)
        camera.lens.coc_diameter(torch.tensor([0.0]))  # a depth of 0 is trusted
        with pytest.raises(ValueError, match="f_number must be finite and > 0"):
            ThinLens(0.05, -2.0, 2.0)  # a number: always checked
    with pytest.raises(ValueError, match="depth must be > 0"):
        camera.lens.coc_diameter(torch.tensor([0.0]))
    assert set_checks(True) is True
