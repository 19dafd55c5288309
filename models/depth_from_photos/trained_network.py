"""A network trained for one camera (`defocus train`) as a method of `estimate_depth`.

Such a network has learnt the blur of its training camera at its training resolution, so it runs
on the photos as they are (no working resolution) and answers depth within the range it was
trained for.
"""

from __future__ import annotations

from torch import Tensor, nn

from optics import CameraSettings

from .tiling import check_tiling, run_network


class TrainedNetwork(nn.Module):
    """A depth network of `defocus train` (`models.loading.load_depth_model`), called like every
    method of `estimate_depth`.

    Args:
        network: the trained network (`models.networks.build_network`), called as
            `network(image, focused, settings)`, depth `(B,1,H,W)` metres.
        input_mode: its input mode, `"aif"` (the all-in-focus photo only) or `"aif+focused"`.
        n_focus: focused photos the network reads in `"aif+focused"` mode.
        depth_range: `(near, far)` metres the network was trained for.
        max_pixels: photos up to this many pixels go through whole; larger ones in tiles of
            `tile` pixels square with `overlap` pixels of context (memory stays bounded; the
            networks' group normalisation sees each tile's statistics, so seams may show).
        tile: side of a tile's kept centre, pixels.
        overlap: context around each tile, pixels.

    Example:
        >>> import torch
        >>> from models.networks import build_network
        >>> model = TrainedNetwork(build_network("small", "aif", 0, 1.0, 10.0, width=4), "aif", 0,
        ...                        (1.0, 10.0))
        >>> model(torch.zeros(1, 3, 4, 4), None, None, 1.0, 10.0)["depth"].shape
        torch.Size([1, 1, 4, 4])
    """

    #: It runs on the photos at their own resolution.
    native_resolution = True
    #: It needs an all-in-focus photo.
    needs_image = True

    def __init__(self, network: nn.Module, input_mode: str, n_focus: int,
                 depth_range: tuple[float, float], max_pixels: int = 2_000_000,
                 tile: int = 1024, overlap: int = 64):
        super().__init__()
        check_tiling(tile, overlap)
        self.max_pixels, self.tile, self.overlap = int(max_pixels), int(tile), int(overlap)
        self.network, self.input_mode, self.n_focus = network, input_mode, int(n_focus)
        self.depth_range = (float(depth_range[0]), float(depth_range[1]))

    def forward(self, image: Tensor, focused: Tensor | None, settings: CameraSettings | None,
                near: float, far: float) -> dict[str, Tensor]:
        """Depth `(B,1,H,W)` metres of the all-in-focus `image` `(B,3,H,W)` and, in
        `"aif+focused"` mode, the `n_focus` `focused` photos `(B,F,3,H,W)` with their settings
        (the caller gives what the network reads); `near` and `far` are not used (the network
        answers within its trained range)."""
        return {"depth": run_network(self.network, image, focused, settings, self.max_pixels,
                                     self.tile, self.overlap)}
