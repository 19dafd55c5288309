"""Depth networks: shapes, depth range, input modes, gradients, errors."""

import pytest
import torch

from models.depth_head import DepthHead
from models.networks import (
    PaperDepthNet,
    SmallDepthNet,
    build_network,
    camera_channels,
    defocus_cues,
)
from optics import CameraSettings


def _camera(b, n=2):
    return CameraSettings(0.05, 2.0, [[2.0, 6.0, 9.0][:n]] * b, 180e-6).to(torch.float32)


@pytest.mark.parametrize("scales", [3, 5])
@pytest.mark.parametrize("size", [(16, 16), (19, 27)])
@pytest.mark.parametrize("mode", ["aif", "aif+focused"])
def test_small_net_shapes_and_range(mode, size, scales):
    torch.manual_seed(0)
    net = SmallDepthNet(mode, n_focus=2, depth_min=1.5, depth_max=6.0, width=4, scales=scales)
    image = torch.rand(2, 3, *size)
    focused = torch.rand(2, 2, 3, *size)
    with torch.no_grad():
        depth = net(image, focused, _camera(2)) if mode != "aif" else net(image)
    assert depth.shape == (2, 1, *size)
    assert float(depth.min()) > 1.5 and float(depth.max()) < 6.0


def test_head_maps_logits_to_metres():
    head = DepthHead(2.0, 10.0)
    torch.testing.assert_close(head(torch.tensor([0.0, -100.0, 100.0])),
                               torch.tensor([6.0, 2.0, 10.0]))
    with pytest.raises(ValueError, match="depth_min"):
        DepthHead(5.0, 1.0)


def test_camera_channels_by_hand():
    ch = camera_channels(_camera(1), depth_max=6.0)
    expected_coc = 0.05**2 / (2.0 * (2.0 - 0.05) * 180e-6) / 10
    torch.testing.assert_close(ch[0, 0], torch.tensor([2.0 / 6.0, expected_coc]))


def test_defocus_cues_measure_blur():
    import kornia

    image = torch.rand(1, 3, 32, 32, generator=torch.Generator().manual_seed(0))
    mild = kornia.filters.gaussian_blur2d(image, (9, 9), (0.8, 0.8))
    strong = kornia.filters.gaussian_blur2d(image, (9, 9), (1.6, 1.6))
    cues = defocus_cues(image, torch.stack([mild, strong], 1))
    inner = cues[..., 8:-8, 8:-8]
    assert bool((inner[:, 1] < inner[:, 0]).all()) and bool((inner[:, 0] < 0).all())


def test_focused_input_changes_output():
    torch.manual_seed(0)
    net = SmallDepthNet("aif+focused", 2, 1.0, 10.0, width=4)
    image = torch.rand(1, 3, 12, 12)
    a = net(image, torch.rand(1, 2, 3, 12, 12), _camera(1))
    b = net(image, torch.rand(1, 2, 3, 12, 12), _camera(1))
    assert not torch.allclose(a, b)


@pytest.mark.parametrize("scales", [2, 3, 5])
def test_gradients_reach_all_parameters(scales):
    torch.manual_seed(0)
    net = SmallDepthNet("aif+focused", 2, 1.0, 10.0, width=4, scales=scales)
    net(torch.rand(1, 3, 12, 12), torch.rand(1, 2, 3, 12, 12), _camera(1)).mean().backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in net.parameters())


def test_more_scales_see_farther():
    """The share of a pixel's input gradient from more than 20 px away: about 0.2 with three
    scales (GroupNorm's image statistics alone reach that far) and 0.6 with five."""
    image = torch.rand(1, 3, 96, 96, generator=torch.Generator().manual_seed(1))
    rows, cols = torch.meshgrid(torch.arange(96), torch.arange(96), indexing="ij")
    far = (rows - 48) ** 2 + (cols - 48) ** 2 > 20 ** 2
    share = {}
    for scales in (3, 5):
        torch.manual_seed(0)
        net = SmallDepthNet("aif", depth_min=1.0, depth_max=10.0, width=4, scales=scales).eval()
        x = image.clone().requires_grad_()
        net(x)[0, 0, 48, 48].backward()
        grad = x.grad.abs().sum(1)[0]
        share[scales] = float(grad[far].sum() / grad.sum())
    assert share[3] < 0.3 and share[5] > 2 * share[3], share


def test_position_is_the_row_in_the_input():
    net = SmallDepthNet("aif+focused", 2, 1.0, 10.0, width=4, position=True)
    x = net.with_rows(net.assemble_input(torch.rand(2, 3, 5, 7), torch.rand(2, 2, 3, 5, 7),
                                         _camera(2)))
    assert x.shape[1] == net.in_channels == SmallDepthNet("aif+focused", 2, width=4).in_channels + 1
    expected = torch.tensor([-1.0, -0.5, 0.0, 0.5, 1.0]).view(5, 1).expand(5, 7)
    assert torch.equal(x[0, -1], expected) and torch.equal(x[1, -1], expected)


def test_tiles_of_a_position_network_read_the_photos_rows():
    """`run_network` above `max_pixels`: each tile reads its rows in the whole photo, not its
    own -1..1."""
    from models.depth_from_photos.tiling import run_network

    net = SmallDepthNet("aif", width=4, position=True)
    seen, logits = [], net._logits
    net._logits = lambda x: (seen.append(x[0, -1].clone()), logits(x))[1]
    run_network(net, torch.rand(1, 3, 20, 12), max_pixels=100, tile=8, overlap=2)
    whole = SmallDepthNet.row_map(20, 12)[0, 0]
    assert len(seen) == 6  # rows 0, 8, 16 x columns 0, 8
    torch.testing.assert_close(seen[2], whole[6:18, 0:10])  # the tile at row 8, column 0
    torch.testing.assert_close(seen[5], whole[14:20, 6:12])


def test_three_scales_keep_the_weight_names():
    """Checkpoints of the three-scale network load: enc1..enc3, dec2, dec1, out, in order."""
    names = [name for name, _ in SmallDepthNet("aif", width=4).named_children()]
    assert names == ["head", "enc1", "enc2", "enc3", "dec2", "dec1", "out"]
    deeper = [name for name, _ in SmallDepthNet("aif", width=4, scales=4).named_children()]
    assert deeper == ["head", "enc1", "enc2", "enc3", "enc4", "dec3", "dec2", "dec1", "out"]


def test_gradcheck_input_float64():
    torch.manual_seed(0)
    net = SmallDepthNet("aif", depth_min=1.0, depth_max=10.0, width=2).double()
    image = torch.rand(1, 3, 8, 8, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(net, (image,))


def test_paper_net_forward_and_modes():
    torch.manual_seed(0)
    net = PaperDepthNet("aif+focused", n_focus=2, depth_min=1.0, depth_max=10.0).eval()
    assert sum(p.numel() for p in net.parameters()) > 20e6
    with torch.no_grad():
        depth = net(torch.rand(1, 3, 48, 64), torch.rand(1, 2, 3, 48, 64), _camera(1))
    assert depth.shape == (1, 1, 48, 64)
    assert float(depth.min()) > 1.0 and float(depth.max()) < 10.0


def test_errors():
    with pytest.raises(ValueError, match="input_mode"):
        SmallDepthNet("stereo")
    with pytest.raises(ValueError, match="network"):
        build_network("resnet", "aif", 0, 1.0, 10.0)
    net = SmallDepthNet("aif+focused", 2, 1.0, 10.0, width=4)
    with pytest.raises(ValueError, match="focused"):
        net(torch.rand(1, 3, 8, 8))
    with pytest.raises(ValueError, match="focused"):
        net(torch.rand(1, 3, 8, 8), torch.rand(1, 3, 3, 8, 8), _camera(1, 3))
    with pytest.raises(ValueError, match="image"):
        net(torch.rand(1, 1, 8, 8))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_depth_head_even_in_inverse_depth(dtype):
    """`spacing="inverse"`: equal logit steps give equal steps of inverse depth, the range's ends
    at the sigmoid's ends, the harmonic middle at zero; differentiable."""
    head = DepthHead(0.5, 10.0, spacing="inverse")
    logits = torch.tensor([-60.0, 0.0, 60.0], dtype=dtype)
    torch.testing.assert_close(head(logits), torch.tensor([0.5, 2 / (2 + 0.1), 10.0], dtype=dtype))
    sig = torch.sigmoid(torch.linspace(-3, 3, 7, dtype=torch.float64))
    inverse = 1 / head(torch.logit(sig))
    torch.testing.assert_close(inverse, 2.0 - (2.0 - 0.1) * sig)  # linear in the sigmoid
    x = torch.randn(5, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(head, (x,))
    with pytest.raises(ValueError, match="spacing must be one of"):
        DepthHead(0.5, 10.0, spacing="log")


def test_build_network_and_config_take_the_spacing(tmp_path):
    from models.networks import build_network
    from models.training.config import TrainConfig

    net = build_network("small", "aif", 0, 0.5, 10.0, width=8, depth_spacing="inverse")
    assert net.head.spacing == "inverse" and not list(net.head.parameters())
    assert TrainConfig(depth_spacing="inverse").depth_spacing == "inverse"
    with pytest.raises(ValueError, match="depth_spacing must be one of"):
        TrainConfig(depth_spacing="linear")
    assert TrainConfig(width=4, scales=4, input_mode="aif").build_network().scales == 4
    with pytest.raises(ValueError, match="scales must be an integer >= 2, got 1"):
        TrainConfig(scales=1)


def test_sweep_channels_are_read_through_the_given_aperture():
    """`sweep=K` adds the K cost channels of `sweep_channels` to an "aif+focused" input
    (nothing in "aif" mode), rendered through the aperture the call names: a code's and the
    disk's differ, and so does the depth."""
    from models.depth_from_photos.sweep import sweep_channels
    from optics import Disk, Mask, disk_mask

    settings = CameraSettings(0.05, 2.0, [2.0], 1e-4)
    plain = SmallDepthNet("aif+focused", 1, width=4)
    net = SmallDepthNet("aif+focused", 1, width=4, sweep=6)
    assert net.in_channels == plain.in_channels + 6
    assert SmallDepthNet("aif", width=4, sweep=6).in_channels == 3
    gen = torch.Generator().manual_seed(0)
    image, focused = torch.rand(1, 3, 24, 24, generator=gen), torch.rand(1, 1, 3, 24, 24,
                                                                         generator=gen)
    code = Mask(torch.rand(8, 8, generator=gen) * disk_mask(8, torch.float32))
    x = net.assemble_input(image, focused, settings, code)
    torch.testing.assert_close(x[:, -6:], sweep_channels(image, focused, settings, 1.0, 10.0,
                                                         6, code))
    with torch.no_grad():
        by_code, by_disk = net(image, focused, settings, aperture=code), \
            net(image, focused, settings, aperture=Disk())
    assert not torch.allclose(by_code, by_disk)


@pytest.mark.parametrize("spacing", ["depth", "inverse"])
def test_head_logits_invert_the_head(spacing):
    """`DepthHead.logits` is `forward`'s inverse inside the range, clamped at its ends."""
    head = DepthHead(0.5, 10.0, spacing=spacing)
    depth = torch.tensor([0.6, 1.0, 2.0, 5.0, 9.5], dtype=torch.float64)
    torch.testing.assert_close(head(head.logits(depth)), depth)
    assert torch.isfinite(head.logits(torch.tensor([0.5, 10.0]))).all()


def test_sweep_network_refines_the_cheapest_candidate():
    """With its own logits zeroed, a `sweep=K` network returns the depth of the candidate
    whose windowed cost is lowest, found here from `sweep_cost` itself; its own logits move
    that depth, and a stated side is refused (the sweep finds the side)."""
    from models.depth_from_photos.sweep import SWEEP_WINDOW_PX, sweep_cost
    from models.depth_from_photos.thin_lens import box_filter

    settings = CameraSettings(0.05, 2.0, [2.0], 1e-4)
    net = SmallDepthNet("aif+focused", 1, 0.5, 10.0, width=4, depth_spacing="inverse",
                        sweep=8)
    gen = torch.Generator().manual_seed(0)
    image, focused = torch.rand(1, 3, 24, 24, generator=gen), torch.rand(1, 1, 3, 24, 24,
                                                                         generator=gen)
    cost = box_filter(sweep_cost(image, focused, settings, 0.5, 10.0, 8), SWEEP_WINDOW_PX)
    cheapest = 1 / torch.linspace(0.1, 2.0, 8)[cost.argmin(1, keepdim=True)]
    with torch.no_grad():
        moved = net(image, focused, settings)
        net.out.weight.zero_(), net.out.bias.zero_()
        # the range's ends are 1e-3 of the sigmoid inside them
        torch.testing.assert_close(net(image, focused, settings), cheapest, rtol=2e-3, atol=0)
    assert not torch.allclose(moved, cheapest)
    with pytest.raises(ValueError, match="sweep=8 needs side 'both'"):
        SmallDepthNet("aif+focused", 1, 0.5, 10.0, side="beyond", focus_distance=2.0, sweep=8)


def test_config_sweep_inputs():
    from models.training import TrainConfig

    assert TrainConfig(sweep_inputs=8, n_focus=2).build_network().sweep == 8
    with pytest.raises(ValueError, match="sweep_inputs must be 0"):
        TrainConfig(sweep_inputs=1)
    with pytest.raises(ValueError, match="needs input_mode 'aif\\+focused'"):
        TrainConfig(sweep_inputs=8, input_mode="aif")
