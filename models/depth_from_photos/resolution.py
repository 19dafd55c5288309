"""The working resolution: blur in a readable range of pixels, at a bounded cost.

Depth from defocus reads blur in pixels, and reads it well only within a range (about 0.5 to 20
pixels for the sweep). A 12-megapixel photo of a fast lens blurs by a hundred pixels and more, and
its cost volume would take gigabytes. So every method runs at a working resolution: the photos
area-averaged down until the largest blur over the stated depth range is what the method reads
well and the pixel count is bounded (`working_scale`), with the pixel pitch grown by the same
factor (`to_working_resolution`). `run_at_working_resolution` aligns the shots there, runs the
method, brings the depth back to the photos' size, and, where the scene holds a narrower range
of depths than stated, runs again over that range at a finer resolution (`scene_range`),
widening it where that pass shows the first one cut the scene short (`widen_cut_range`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from optics import CameraSettings, align_shots
from optics.checks import values_checked
from optics.progress import progress_bar

from .rules import refuse_broken


def working_scale(settings: CameraSettings, near: float, far: float, shape: tuple[int, int],
                  max_coc_px: float = 12.0, max_pixels: int = 1_500_000) -> float:
    """The downscale factor (<= 1) of the photos for `DepthFromDefocus`: the largest CoC over
    `[near, far]` at most `max_coc_px` pixels (what `BlurNet` reads well) and at most
    `max_pixels` pixels (time and memory).

    Example:
        >>> s = CameraSettings(0.05, 1.4, [2.0, 6.0], 6e-6)  # 50 mm f/1.4, 6 um pixels
        >>> round(working_scale(s, 1.0, 10.0, (3000, 4000)), 3)
        0.048
    """
    largest = settings.largest_coc_px(near, far)
    return min(1.0, max_coc_px / max(largest, 1e-9), math.sqrt(max_pixels / (shape[0] * shape[1])))


#: The fewest pixels on each side of a photo that the methods read.
MIN_PHOTO_SIDE = 6
#: The fewest pixels on each side of the working resolution (the 3x3 median of every method);
#: a blur so large, from a tiny f-number or pixel pitch, that the photos would shrink below it
#: is refused.
MIN_WORKING_SIDE = 3


def check_working_size(settings: CameraSettings, near: float, far: float,
                       shape: tuple[int, int], scale: float) -> None:
    """Refuse photos of `shape` `(H, W)` that are, or at the working `scale` would be, smaller
    than `MIN_PHOTO_SIDE` (the photos) or `MIN_WORKING_SIDE` (the working resolution) pixels
    a side (tiny photos, or a blur so large, from a tiny
    f-number or pixel pitch, that the photos would shrink to nothing).

    Example:
        >>> check_working_size(CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4), 1.0, 10.0, (4, 4), 1.0)
        Traceback (most recent call last):
        ...
        ValueError: the photos are 4x4 pixels; depth from defocus needs at least 6 pixels on each side
    """
    h, w = shape
    small = (round(h * scale), round(w * scale))
    refuse_broken([
        (min(h, w) < MIN_PHOTO_SIDE, lambda: f"the photos are {h}x{w} pixels; depth from "
         f"defocus needs at least {MIN_PHOTO_SIDE} pixels on each side"),
        (min(small) < MIN_WORKING_SIDE, lambda: f"over the depth range {near:g}-{far:g} m the "
         f"largest blur is {settings.largest_coc_px(near, far):.3g} pixels (f-number "
         f"{settings.f_number.reshape(-1).tolist()}, pixel pitch "
         f"{settings.pixel_pitch.reshape(-1).tolist()} m), so the {h}x{w} photos would be read "
         f"at {small[0]}x{small[1]} pixels (at least {MIN_WORKING_SIDE} a side needed): check "
         "the f-number, the pixel pitch (metres) and the depth range")])


def run_at_working_resolution(
    model: nn.Module, image: Tensor | None, focused: Tensor, settings: CameraSettings,
    near: float, far: float, max_coc_px: float | None = None, max_pixels: int = 1_500_000,
    align: bool = True, refine_range: bool = True, progress: bool = False,
    fold: Callable[[Tensor], Tensor] | None = None,
) -> dict[str, Tensor | float]:
    """Depth of one scene at the photos' resolution, computed at the working resolution.

    Behind `estimate_depth`'s door: the arguments are taken as checked there.

    Args:
        model: a method of `estimate_depth` (e.g. `SweepDepth`), called as
            `model(image, focused, settings, near, far)` at the working resolution.
        image: all-in-focus photo `(3,H,W)`, linear, or None for a method that reads the
            focused photos alone (they are then aligned to the first).
        focused: `(F,3,H,W)` focused photos, linear, `F >= 2` (1 works with an all-in-focus
            photo but stays ambiguous around the focus plane).
        settings: their `(F,)` settings at the photos' resolution (effective pixel pitch).
        near: nearest depth of the scene, metres.
        far: farthest depth, metres.
        max_coc_px: see `working_scale`; by default the model's `max_coc_px` (the largest blur
            it reads well).
        max_pixels: see `working_scale`.
        align: move (and, for a lens that breathes, scale) each focused photo onto the
            all-in-focus one first (`optics.align_shots`, at the working resolution): a
            misalignment would read as blur.
        refine_range: a stated range wider than the scene costs resolution: the largest blur
            over `[near, far]` sets the working resolution, and a scene much farther than
            `near` never blurs that much. With this on, a first pass finds the depths the scene
            holds (`scene_range`); if that range allows a working resolution at least
            `REFINE_GAIN` times finer, the depth is computed again there, over that range;
            where that pass piles its depths at a limit the first pass set, that side is
            widened and the depth computed again (`widen_cut_range`, at most
            `MAX_WIDENINGS` times).
        progress: count the passes over the depth range in a progress bar.
        fold: a statement about the scene applied to the first pass's depth before the
            scene's range is read from it (`estimate_depth`'s `side`: each blur both sides of
            one focus plane explain put on the stated one), so that the finer pass spans the
            scene, not its mirror image too.

    Returns:
        dict with `depth` and `confidence` `(1,H,W)`, `blur` `(F,h,w)` at the working
        resolution, `scale` (working / photo resolution), `depth_range` (the `(near, far)`
        metres of the pass kept), `shifts` `(F,2)`, `zooms` `(F,)` and `rotations` `(F,)`: how
        far each focused photo had moved `(dy, dx)`, in the photos' pixels, how much it was
        magnified and how far it was turned, in degrees, clockwise on screen (zero, one and zero
        without `align`).
    """
    h, w = focused.shape[-2:]
    max_coc_px = model.max_coc_px if max_coc_px is None else max_coc_px
    scale = working_scale(settings, near, far, (h, w), max_coc_px, max_pixels)
    check_working_size(settings, near, far, (h, w), scale)
    passes = progress_bar(total=None, desc="depth", unit=" pass", bar_format=PASSES_FORMAT,
                          disable=not progress)
    out = _run_at(model, image, focused, settings, near, far, scale, align)
    passes.update()
    if refine_range:
        inner = scene_range(out["depth"] if fold is None else fold(out["depth"]), near, far)
        finer = working_scale(settings, *inner, (h, w), max_coc_px, max_pixels)
        if finer >= REFINE_GAIN * scale:
            out = _run_at(model, image, focused, settings, *inner, finer, align)
            passes.update()
            # a coarse first pass can miss part of the scene: its depths then pile up at the
            # limit it set, and that side is widened and the depth computed again
            for _ in range(MAX_WIDENINGS):
                wider = widen_cut_range(out["depth"], inner, (near, far))
                if wider == inner:
                    break
                inner = wider
                scale = working_scale(settings, *inner, (h, w), max_coc_px, max_pixels)
                out = _run_at(model, image, focused, settings, *inner, scale, align)
                passes.update()
    passes.close()
    return out


#: The progress bar of `run_at_working_resolution`: how many passes over the depth range are
#: done (their number is known only as they end).
PASSES_FORMAT = "{desc}: passes over the depth range done: {n_fmt} [{elapsed}]"
#: How much finer (ratio of working scales) the scene's own depth range must allow before
#: `run_at_working_resolution` computes the depth a second time.
REFINE_GAIN = 1.25
#: Share of the pixels at a limit the first pass set (not a stated one) that says the scene
#: goes on beyond it (`widen_cut_range`).
PILED_SHARE = 0.02
#: The most times `run_at_working_resolution` widens a refined range.
MAX_WIDENINGS = 2


def widen_cut_range(depth: Tensor, kept: tuple[float, float], stated: tuple[float, float],
                    share: float = PILED_SHARE) -> tuple[float, float]:
    """The range `kept` `(near, far)` metres, widened on each side where it cut into the scene.

    A side counts as cut where its limit lies inside the `stated` range and more than `share`
    of the pixels of `depth` (computed over `kept`) sit at that limit (within 0.5 % of the
    range's inverse-depth span): the method could not go further, so the scene likely does.
    That side then moves out by the kept range's own inverse-depth span, never beyond
    `stated`. Returns `kept` itself where nothing was cut.

    Example:
        >>> depth = torch.cat([torch.full((40,), 2.5), torch.linspace(2.5, 5.0, 60)])
        >>> tuple(round(d, 2) for d in widen_cut_range(depth, (2.5, 5.5), (1.0, 15.0)))
        (1.62, 5.5)
        >>> widen_cut_range(depth, (1.0, 5.5), (1.0, 15.0))  # 1 m was stated: not cut
        (1.0, 5.5)
    """
    refuse_broken([(not 0 < share < 1, lambda: f"share must be in (0, 1), got {share!r}")])
    (near, far), (stated_near, stated_far) = kept, stated
    inverse = 1 / depth.detach().flatten().double()
    span = 1 / near - 1 / far
    tolerance = 0.005 * span
    if near > stated_near and float((inverse >= 1 / near - tolerance).double().mean()) > share:
        near = 1 / min(1 / near + span, 1 / stated_near)
    if far < stated_far and float((inverse <= 1 / far + tolerance).double().mean()) > share:
        far = 1 / max(1 / far - span, 1 / stated_far)
    return near, far


def scene_range(depth: Tensor, near: float, far: float, tail: float = 0.01,
                margin: float = 0.15) -> tuple[float, float]:
    """The depths `(near, far)` metres a depth map holds, within `[near, far]`: its `tail` and
    `1 - tail` quantiles in inverse depth, widened by `margin` times their span on each side
    (a coarse first estimate is off by some of it), and by at least 2 % of the stated range's
    inverse-depth span (a map of one depth still gets a range).

    Example:
        >>> depth = torch.linspace(2.0, 5.0, 1000).reshape(1, 1, 20, 50)
        >>> tuple(round(d, 2) for d in scene_range(depth, 1.0, 15.0, tail=0.0))
        (1.83, 6.45)
    """
    inverse = 1 / depth.detach().flatten().double()
    inverse = inverse[:: max(1, inverse.numel() // 100_000)]
    quantiles = torch.tensor([tail, 1 - tail], dtype=inverse.dtype, device=inverse.device)
    lo, hi = torch.quantile(inverse, quantiles).tolist()
    pad = max(margin * (hi - lo), 0.02 * (1 / near - 1 / far))
    return 1 / min(hi + pad, 1 / near), 1 / max(lo - pad, 1 / far)


def to_working_resolution(image: Tensor, focused: Tensor, settings: CameraSettings,
                          scale: float) -> tuple[Tensor, CameraSettings]:
    """The all-in-focus photo `(3,H,W)` and the focused ones `(F,3,H,W)` stacked `(1+F,3,h,w)`
    at `scale` (`working_scale`; area-averaged, at least 8x8 pixels), and their settings there
    (the effective pixel pitch grows by the same factor)."""
    h, w = image.shape[-2:]
    size = (max(8, round(h * scale)), max(8, round(w * scale)))
    if scale < 1:  # photo by photo: no full-resolution copy of the stack
        small = torch.cat([F.interpolate(photo[None], size=size, mode="area")
                           for photo in (image, *focused)])
    else:
        small = torch.cat([image[None], focused])
    return small, settings.replace(pixel_pitch=settings.pixel_pitch * (w / size[1]))


def _run_at(model: nn.Module, image: Tensor | None, focused: Tensor, settings: CameraSettings,
            near: float, far: float, scale: float, align: bool) -> dict[str, Tensor | float]:
    """`run_at_working_resolution`'s pass over `[near, far]` at the working `scale`. Without
    an all-in-focus `image` the first focused photo is the reference the others are aligned
    to."""
    h, w = focused.shape[-2:]
    if image is None:
        small, effective = to_working_resolution(focused[0], focused[1:], settings, scale)
        first = 1  # the reference is shot 0 itself
    else:
        small, effective = to_working_resolution(image, focused, settings, scale)
        first = 0
    size = small.shape[-2:]
    moving = small[1:][None]
    identity = torch.tensor([0.0, 0.0, 1.0, 0.0], dtype=small.dtype,
                            device=small.device).expand(1, moving.shape[1], 4)
    shots, motions = align_shots(small[:1], moving) if align and moving.shape[1] \
        else (moving, identity)
    if first:
        shots = torch.cat([small[:1][None], shots], 1)
        motions = torch.cat([identity[:, :1], motions], 1)
    with torch.no_grad(), values_checked():  # the photos were read at estimate_depth's door
        out = model(None if first else small[:1], shots, effective.to(small.dtype), near, far)
    depth = F.interpolate(out["depth"], size=(h, w), mode="bilinear", align_corners=False)
    confidence = F.interpolate(out["confidence"], size=(h, w), mode="bilinear",
                               align_corners=False)
    return {"depth": depth[0], "confidence": confidence[0], "blur": out["blur"][0],
            "scale": size[1] / w, "depth_range": (near, far),
            "shifts": motions[0, :, :2] * (w / size[1]), "zooms": motions[0, :, 2],
            "rotations": torch.rad2deg(motions[0, :, 3])}
