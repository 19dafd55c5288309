"""An all-in-focus image from focused shots and the blur each has at the depth found.

Focus stacking: every pixel is taken mostly from the shot that is sharpest there. With the depth
known, the thin lens says how blurred each shot is at every pixel (`blur`, pixels); the shots are
blended with weights that fall off quickly with that blur (a soft minimum, so seams between shots
are gradual), after their exposures are matched and each is moved back onto the first shot by
the motion the alignment found. No deconvolution: where every shot is blurred (between two
distant focus planes) the result is as sharp as the sharpest shot there.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from optics import undo_motion
from optics.checks import check_shape

from .photometry import exposure_gain
from .rules import refuse_broken
from .thin_lens import box_filter

#: Blur difference (pixels at the working resolution) over which a shot's weight falls by e.
SOFTNESS_PX = 0.35


def fusion_weights(blur: Tensor, size: tuple[int, int], softness_px: float = SOFTNESS_PX
                   ) -> Tensor:
    """Per-shot weights `(F,H,W)` summing to 1 at every pixel, from the blur `(F,h,w)` (pixels)
    of each shot: `softmax(-blur / softness_px)` over the shots, smoothed over 3x3 pixels and
    resized to `size`.

    Example:
        >>> blur = torch.tensor([0.0, 3.0]).reshape(2, 1, 1).expand(2, 4, 4)
        >>> w = fusion_weights(blur, (8, 8))
        >>> w.shape, bool(w[0].min() > 0.99)
        (torch.Size([2, 8, 8]), True)
    """
    check_shape("blur", blur, ["F", "H", "W"])
    refuse_broken([(not softness_px > 0,
                    lambda: f"softness_px must be > 0 pixels, got {softness_px!r}")])
    weights = torch.softmax(-blur / softness_px, 0)
    weights = box_filter(weights[None], 3)
    weights = F.interpolate(weights, size=size, mode="bilinear", align_corners=False)[0]
    return weights / weights.sum(0, keepdim=True)


def fuse_all_in_focus(shots: Tensor, blur: Tensor, motions: Tensor | None = None) -> Tensor:
    """The all-in-focus image `(3,H,W)` of focused `shots` `(F,3,H,W)` (linear).

    Args:
        shots: the photos as taken (not aligned), linear.
        blur: `(F,h,w)` blur of each shot in pixels at any resolution (`estimate_depth`'s
            `blur`, at its working resolution).
        motions: `(F,4)` `(dy, dx, zoom, angle)` of each shot relative to the first, in the
            shots' pixels and radians (from the alignment); None if they are aligned.

    Example:
        >>> sharp = torch.rand(3, 16, 16)
        >>> blurred = torch.full((3, 16, 16), 0.5)
        >>> blur = torch.stack([torch.zeros(16, 16), torch.full((16, 16), 4.0)])
        >>> fused = fuse_all_in_focus(torch.stack([sharp, blurred]), blur)
        >>> torch.allclose(fused, sharp, atol=1e-3)
        True
    """
    check_shape("shots", shots, ["F", "3", "H", "W"])
    refuse_broken([(blur.shape[0] != shots.shape[0],
                    lambda: f"blur holds {blur.shape[0]} shots but shots {shots.shape[0]}")])
    weights = fusion_weights(blur.to(shots.dtype), tuple(shots.shape[-2:]))
    fused = shots[0] * weights[0]
    reference = shots[0].mean((-2, -1), keepdim=True)  # measured once
    for i in range(1, shots.shape[0]):  # one aligned copy at a time (memory)
        shot = shots[i]
        if motions is not None:
            shot = undo_motion(shot[None], motions[i].to(shots.dtype))[0]
        # the exposure matched with the weight (a per-channel gain, measured on the shot as
        # taken: the motion's resampling commutes with it)
        gain = exposure_gain(reference, shots[i])
        fused.addcmul_(shot, weights[i] * gain)
    return fused
