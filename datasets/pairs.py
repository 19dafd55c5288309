"""Aperture pairs as the renderer models them: registered shots, the calibrated blur and exposure.

A pair of real photos of one view (a nearly sharp `image`, e.g. at f/8, and a defocused
`focused` photo, e.g. at f/2.8) differs from the renderer's model of it in more than defocus:

- the shots are not registered (a tripod settles, a mirror slaps: 0.3 to 4 pixels on the DSLR
  set). Read as defocus, a shift adds blur, and a loss through the renderer then prefers the
  blur of a depth range's far end to the true depth. `register_focused` moves the focused photos
  onto the image (`optics.align_shots`);
- the reference is not sharp, the defocused photo is blurred even in focus (the *floor*) and
  exposed a little differently: `relative_pair` gives the image and the camera of the blur from
  the reference to the defocused photo, with the fitted floor and exposure gain of a calibration
  (`datasets.calibration`, `defocus calibrate`).

Both work on any sample of the sample format (not only `datasets.DSLR`'s).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import torch
from torch import Tensor

from optics import CameraSettings, align_shots, render_defocus, undo_motion, warp


def register_focused(sample: Mapping[str, Any]) -> dict[str, Any]:
    """`sample` with its `focused` photos `(F,3,H,W)` registered onto its `image` `(3,H,W)`;
    `"motion"` `(F,4)` holds the motion found (`dy, dx, zoom, angle` of each focused photo
    relative to the image, `optics.estimate_motion`). Estimated in float64, returned in the
    photos' dtype.

    A translation is undone exactly (`optics.translate`, no resampling). Where the lens
    breathed or the camera turned (beyond `optics.alignment.ZOOM_TOLERANCE_PX` at the corners) the motion must be
    resampled, and resampling blurs: read as defocus, that blur of the focused photo alone would
    bias a loss toward more blur. With one focused photo the motion is then split, half undone
    on it and half applied to the image, so both are resampled alike and the blur between them
    is the defocus alone; with several, they are moved onto the image (`optics.align_shots`).

    Example:
        >>> import kornia
        >>> from optics import translate
        >>> image = kornia.filters.gaussian_blur2d(torch.rand(1, 3, 48, 48), (7, 7), (1.0, 1.0))
        >>> focused = translate(image, torch.tensor([[1.0, -0.5]]))
        >>> out = register_focused({"image": image[0], "focused": focused})
        >>> motion = out["motion"]
        >>> tuple(motion[0, :2].round(decimals=1).tolist())
        (1.0, -0.5)
    """
    image, focused = sample["image"][None].double(), sample["focused"][None].double()
    aligned, motion = align_shots(image, focused)
    if focused.shape[1] == 1 and bool((motion[0, 0, 2:] != torch.tensor(
            [1.0, 0.0], dtype=motion.dtype)).any()):
        dy, dx, zoom, angle = motion[0, 0]
        half = torch.stack([dy / 2, dx / 2, zoom.sqrt(), angle / 2])
        aligned = undo_motion(focused[:, 0], half)[:, None]
        image = warp(image, half[None, :2], half[2:3], half[3:4])
    return {**sample, "image": image[0].to(sample["image"].dtype),
            "focused": aligned[0].to(sample["focused"].dtype), "motion": motion[0].float()}


def soften(image: Tensor, camera: CameraSettings, floor_px: float) -> Tensor:
    """`image` `(3,H,W)` blurred by the camera's PSF at a constant `floor_px` (CoC diameter,
    pixels): the blur the defocused photos have even in focus (`focus_floor_px` of a fitted
    camera JSON). Zero leaves it as it is.

    Example:
        >>> image = torch.rand(3, 16, 16)
        >>> camera = CameraSettings(0.035, 2.8, [1.7], 6e-5, "gaussian:0.5")
        >>> bool(soften(image, camera, 1.5).std() < image.std()), soften(image, camera, 0) is image
        (True, True)
    """
    if floor_px <= 0:
        return image
    floor = torch.full((1, 1, *image.shape[-2:]), float(floor_px), dtype=image.dtype,
                       device=image.device)
    return render_defocus(image[None], floor, psf=camera.aperture_module())[0]


def relative_pair(image: Tensor, camera: CameraSettings, reference_f_number: float,
                  floor_px: float = 0.0, gain: Sequence[float] | None = None,
                  ) -> tuple[Tensor, CameraSettings]:
    """The reference `image` `(3,H,W)` and the camera of the blur from it to the defocused
    photo: the reference's own blur taken out of the f-number (`N / sqrt(1 - (N / N_ref)^2)`,
    exact for Gaussian PSFs), `image` blurred by the floor `floor_px` and scaled by the exposure
    `gain` per channel (defocused / reference) of a calibration.

    Raises:
        ValueError: `reference_f_number` does not exceed the camera's f-number.

    Example:
        >>> camera = CameraSettings(0.035, 2.8, [1.7], 6e-5, "gaussian:0.5")
        >>> image, relative = relative_pair(torch.full((3, 8, 8), 0.5), camera, 8.0, 0.0,
        ...                                 [1.1, 1.0, 1.0])
        >>> round(float(relative.f_number[0]), 3), round(float(image[0, 0, 0]), 3)
        (2.989, 0.55)
    """
    ratio = camera.f_number / reference_f_number
    if bool((ratio >= 1).any()):
        raise ValueError(f"reference_f_number {reference_f_number} must exceed the camera's "
                         f"f-number {camera.f_number.tolist()} for a relative pair")
    camera = camera.replace(f_number=camera.f_number / (1 - ratio ** 2).sqrt())
    image = soften(image, camera, floor_px)
    if gain is not None:
        image = image * torch.as_tensor(gain, dtype=image.dtype, device=image.device)[:, None, None]
    return image, camera
