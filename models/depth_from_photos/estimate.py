"""`estimate_depth`: depth from photos, one entry point for every method.

A method is a small `nn.Module` called as `method(image, focused, settings, near, far)`, with
`image` `(B,3,H,W)` the all-in-focus photo (or None where the method needs none), `focused`
`(B,F,3,H,W)` the focused shots and `settings` their `(B,F)` `CameraSettings`, returning a dict
with at least `depth` `(B,1,H,W)` metres. Its class attributes say how to run it: `max_coc_px`
(the largest blur it reads well, which sets the working resolution), `needs_image`, and
`native_resolution` (a network trained for one camera runs on the photos as they are).

| method | photos | what it does |
|---|---|---|
| `"sweep"` (`SweepDepth`) | all-in-focus + `F >= 1` focused | a sweep over depth: the all-in-focus photo blurred by the thin lens's PSF must reproduce each focused one |
| `"relative-blur"` (`RelativeBlurDepth`) | `F >= 2` focused | a sweep over depth: of every pair of shots, the sharper one blurred by the relative PSF must reproduce the blurrier one |
| `"focus"` (`DepthFromFocus`) | `F >= 3` focused (a stack) | depth from focus: the peak of each pixel's sharpness over the stack |
| `model=` any method object | as the method needs | e.g. `TrainedNetwork` (a `defocus train` checkpoint) or the experimental `DepthFromDefocus` |

`method="auto"` runs the sweep with an all-in-focus photo and the relative blur without one
(which measured better than depth from focus on every camera of `benchmarks/cameras.py`).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping
from typing import Any

import torch
from torch import Tensor, nn

from optics import CameraSettings
from optics.checks import check_finite, check_shape, is_real_number, is_tracing

from ..depth_head import SIDES
from .all_in_focus import fuse_all_in_focus
from .depth_from_focus import DepthFromFocus
from .relative_blur import RelativeBlurDepth
from .resolution import run_at_working_resolution
from .rules import refuse_broken
from .side import SideStatement, focus_planes
from .sweep import SweepDepth
from .thin_lens import candidate_inverse_depths, mirrored_depths, thin_lens_blur

#: name -> the method's class, built with `progress=...`.
METHODS: dict[str, Callable[..., nn.Module]] = {
    "sweep": SweepDepth, "relative-blur": RelativeBlurDepth, "focus": DepthFromFocus}
#: The least change (pixels, at the photos' resolution) of some shot's blur over the depth
#: range for the shots to tell depths apart.
READABLE_DIFFERENCE_PX = 0.5


def choose_method(has_image: bool, n_shots: int = 2) -> str:
    """The method `estimate_depth(method="auto")` runs for these photos: the sweep with an
    all-in-focus photo, the relative blur between the shots without one.

    Example:
        >>> choose_method(has_image=True), choose_method(has_image=False, n_shots=3)
        ('sweep', 'relative-blur')
    """
    if has_image:
        return "sweep"
    if n_shots < 2:
        raise ValueError(f"depth from focused photos alone needs 2 or more shots, each focused "
                         f"elsewhere, got {n_shots}; or give image, an all-in-focus photo")
    return "relative-blur"


def join_shots(first: CameraSettings, second: CameraSettings) -> CameraSettings:
    """The `(F1 + F2,)` settings of the shots of `first` then those of `second` (one scene, one
    aperture: `second`'s).

    Example:
        >>> joined = join_shots(CameraSettings(0.035, 8.0, [1.7], 5.6e-5),
        ...                     CameraSettings(0.035, 2.8, [1.7], 5.6e-5))
        >>> joined.f_number.tolist()
        [8.0, 2.8]
    """
    if first.is_batched or second.is_batched:
        raise ValueError("join_shots joins the shots of one scene: give unbatched (F,) settings")
    fields = {name: torch.cat([first.tensors()[name].reshape(-1),
                               second.tensors()[name].reshape(-1).to(first.tensors()[name])])
              for name in first.tensors()}
    return CameraSettings(**fields, aperture=second.aperture)


def check_shots_differ(settings: CameraSettings, near: float, far: float) -> None:
    """Refuse shots that cannot tell depths in `[near, far]` metres apart: two shots with the
    same focus distance and f-number (the same blur at every depth), or a range over which no
    shot's blur changes by `READABLE_DIFFERENCE_PX` (at the settings' pixel pitch: the range
    lies far from every focus plane, where the blur hardly changes with depth).

    Example:
        >>> check_shots_differ(CameraSettings(0.05, 2.0, [1.5, 4.0], 5e-6), 1.0, 10.0)
        >>> check_shots_differ(CameraSettings(0.05, 2.0, [1.5, 1.5], 5e-6), 1.0, 10.0)
        Traceback (most recent call last):
        ...
        ValueError: shots 0 and 1 have the same focus distance (1.5 m) and f-number (2): the same blur at every depth; focus them at different distances
    """
    focus = settings.focus_distance.reshape(-1).tolist()
    numbers = settings.f_number.reshape(-1).tolist()
    for i in range(len(focus)):
        for j in range(i + 1, len(focus)):
            if math.isclose(focus[i], focus[j], rel_tol=1e-6) and \
                    math.isclose(numbers[i], numbers[j], rel_tol=1e-6):
                raise ValueError(f"shots {i} and {j} have the same focus distance ({focus[i]:g} "
                                 f"m) and f-number ({numbers[i]:g}): the same blur at every "
                                 "depth; focus them at different distances")
    check_blur_readable(settings, near, far)


def check_blur_readable(settings: CameraSettings, near: float, far: float) -> None:
    """Refuse shots none of whose blur changes by `READABLE_DIFFERENCE_PX` over depths
    `[near, far]` metres (at the settings' pixel pitch): every depth there looks the same.

    Example:
        >>> check_blur_readable(CameraSettings(0.05, 2.0, [1.5, 4.0], 5e-6), 1.0, 10.0)
        >>> check_blur_readable(CameraSettings(0.05, 2.0, [3.0], 0.05), 1.0, 10.0)
        Traceback (most recent call last):
        ...
        ValueError: over the depth range 1-10 m the blur of the shots (focused at 3 m) changes by at most 0.02 pixels (need 0.5): defocus cannot tell depths there apart; check the range and the pixel pitch (metres), or focus the shots within or near the range
    """
    focus = settings.focus_distance.reshape(-1).tolist()
    x = candidate_inverse_depths(near, far, 64, settings.focus_distance)
    blur = thin_lens_blur(settings.batched(1), x[None, None])[0]  # (F,K)
    change = float((blur.amax(1) - blur.amin(1)).max())
    if change < READABLE_DIFFERENCE_PX:
        planes = ", ".join(f"{d:g}" for d in focus)
        raise ValueError(f"over the depth range {near:g}-{far:g} m the blur of the shots "
                         f"(focused at {planes} m) changes by at most {change:.2f} pixels (need "
                         f"{READABLE_DIFFERENCE_PX}): defocus cannot tell depths there apart; "
                         "check the range and the pixel pitch (metres), or focus the shots "
                         "within or near the range")


#: `warn_mirrored` stays quiet where the mirrored depths blur the shots by less than this many
#: pixels (their two sides then look alike and equally sharp).
MIRROR_BLUR_PX = 1.0


def ambiguous_depths(settings: CameraSettings, near: float, far: float
                     ) -> tuple[float, float] | None:
    """The span (metres) of `mirrored_depths` where its blur matters: None where there is no
    such span, or where its ends blur the shots by less than `MIRROR_BLUR_PX` (both sides of
    the focus plane then look alike and sharp, nothing to tell).

    Example:
        >>> s = CameraSettings(0.05, 2.0, [2.0], 1e-4)  # one focus plane, 2 m
        >>> tuple(round(d, 2) for d in ambiguous_depths(s, 1.0, 10.0))
        (1.11, 10.0)
        >>> ambiguous_depths(s, 1.99, 2.01) is None  # a few hundredths of a pixel of blur
        True
    """
    span = mirrored_depths(settings, near, far)
    if span is None:
        return None
    focus = float(settings.focus_distance.reshape(-1)[0])
    # the blur at the span's ends: below about a pixel both sides look sharp, nothing to tell
    largest = float(settings.coc_at_infinity_px().abs().max()) * abs(1 - focus / span[0])
    return None if largest < MIRROR_BLUR_PX else span


def warn_mirrored(settings: CameraSettings, near: float, far: float
                  ) -> tuple[float, float] | None:
    """Warn where the shots cannot tell a depth from its mirror image across their one focus
    plane (`ambiguous_depths`): there the depth may come out on the wrong side of it. Returns
    that span, metres, or None."""
    span = ambiguous_depths(settings, near, far)
    if span is None:
        return None
    focus = float(settings.focus_distance.reshape(-1)[0])
    warnings.warn(
        f"every shot is focused at {focus:g} m, inside the depth range {near:g}-{far:g} m: a "
        f"depth between {span[0]:.2f} and {span[1]:.2f} m blurs them exactly as its mirror "
        "image on the other side of the focus plane, so it may come out on the wrong side. "
        f"Where the scene lies on one side, give that side as the range ({focus:g}-{far:g} m "
        f"beyond the focus plane, {near:g}-{focus:g} m before it), or focus a shot elsewhere",
        UserWarning, stacklevel=3)
    return span


def _coded(model: nn.Module) -> bool:
    """Whether `model` sweeps through a coded aperture: no depths are mirrored then."""
    return bool(getattr(getattr(model, "aperture", None), "oriented", False))


def estimate_depth(
    focused: Tensor, settings: CameraSettings | None, depth_range: tuple[float, float], *,
    image: Tensor | None = None, image_settings: CameraSettings | None = None,
    method: str = "auto", model: nn.Module | None = None,
    options: Mapping[str, Any] | None = None, max_coc_px: float | None = None,
    max_pixels: int = 1_500_000, align: bool = True, refine_range: bool = True,
    progress: bool = False, all_in_focus: bool = True, side: str = "both",
) -> dict[str, Tensor | float | tuple[float, float] | None]:
    """Depth of one scene from its photos and their camera settings.

    Args:
        focused: `(F,3,H,W)` photos, each focused at its own distance, linear intensity (`F`
            may be 0 only for a network that reads the all-in-focus photo alone).
        settings: their `(F,)` settings at the photos' resolution (effective pixel pitch);
            None only where `F` is 0.
        depth_range: `(near, far)` metres the scene lies within.
        image: the all-in-focus photo `(3,H,W)` (a small aperture), linear, where there is one.
        image_settings: the `(1,)` settings of `image` where it is only nearly sharp (an f/8
            shot beside f/2.8 ones): it then counts as one more shot with its own blur, first
            in the stack, and the shots are compared by their relative blur; the returned
            `blur` then holds it first.
        method: a name of `METHODS`, or `"auto"` (`choose_method`).
        model: a method object to run instead of `method` (see the module docstring).
        options: keyword arguments of the method's class (not with `model`; `SweepDepth`'s).
        max_coc_px: the largest blur (pixels) at the working resolution (the method's).
        max_pixels: the most pixels of the working resolution.
        align: align the focused photos first (a misalignment would read as blur).
        refine_range: compute again over the scene's own narrower depth range, finer.
        progress: show progress bars on long work.
        all_in_focus: also return the all-in-focus image: `image` where it is given, else the
            shots fused by the blur each has at the depth found (`fuse_all_in_focus`).
        side: where the scene lies about the shots' one focus plane (which blurs a depth and
            its mirror image alike): `"beyond"`, `"before"` or `"both"` (no statement:
            `warn_mirrored`). See `models.depth_from_photos.side`.

    Returns:
        dict with `depth` `(1,H,W)` metres, `confidence` `(1,H,W)` in [0, 1] (None where the
        method has none), `depth_range` `(near, far)` metres of the pass kept,
        `all_in_focus` `(3,H,W)` (with `all_in_focus=True`), and, for methods run at a working
        resolution, `blur` `(F,h,w)`, `scale`, `shifts`, `zooms` and `rotations` (see
        `run_at_working_resolution`), and `mirrored_depths`: the depths `(nearest, farthest)`
        metres the shots cannot place on either side of their one focus plane
        (`ambiguous_depths`, the span `warn_mirrored` warns of), or None; with a `side`, the
        keys of `side.SideStatement.state`.

    Raises:
        ValueError: for bad photos, depth range, method or `side` (`check_arguments`), a method
            that needs an all-in-focus photo without one, too few shots, or shots that cannot
            tell depths in the range apart (`check_shots_differ`).

    Example:
        >>> import torch
        >>> settings = CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4)
        >>> out = estimate_depth(torch.rand(2, 3, 24, 24), settings, (1.0, 10.0),
        ...                      image=torch.rand(3, 24, 24))
        >>> out["depth"].shape, out["confidence"].shape
        (torch.Size([1, 24, 24]), torch.Size([1, 24, 24]))
    """
    focused, image, (near, far) = check_arguments(focused, settings, depth_range, image,
                                                  image_settings, max_coc_px, max_pixels, side)
    if image_settings is not None:
        focused, settings = torch.cat([image[None], focused]), join_shots(image_settings, settings)
        image = None
    model, stated = (_method_object(method, model, options, progress, image is not None,
                                    len(focused)), SideStatement.of(settings, (near, far), side))
    if getattr(model, "native_resolution", False):
        out = _run_native(model, image, focused, settings, near, far, all_in_focus)
    else:
        _refuse_unreadable(model, image, focused, settings, near, far)
        mirrored = None if side != "both" or _coded(model) else warn_mirrored(settings, near, far)
        out = run_at_working_resolution(model, image, focused, settings,
                                        *(stated.swept_range() if stated else (near, far)),
                                        max_coc_px, max_pixels, align, refine_range, progress,
                                        stated and stated.put)
        out["mirrored_depths"] = mirrored
        if all_in_focus:
            out["all_in_focus"] = image if image is not None else _fused(focused, out, align)
    if stated is not None:
        stated.state(out)
    return out


#: Photo dtypes computed in float32 (and returned as float32): too coarse for the sweep.
_WIDENED = (torch.float16, torch.bfloat16)
#: The farthest end of a depth range (metres): every lens blurs as at infinity long before.
MAX_FAR_M = 1e6
#: The largest value a linear photo in [0, 1] may hold (highlights a raw file's white balance
#: lifts a little above 1 pass; 8-bit or 16-bit code values do not).
MAX_INTENSITY = 2.0
#: The most negative value (a raw file's black level subtracted leaves noise below 0).
MIN_INTENSITY = -0.1


def _is_number(value: Any) -> bool:
    """A real number: Python's, numpy's or a one-element tensor (not a bool)."""
    if isinstance(value, Tensor):
        return value.numel() == 1 and not value.is_complex()
    return is_real_number(value)


def check_arguments(focused: Any, settings: Any, depth_range: Any, image: Any = None,
                    image_settings: Any = None, max_coc_px: float | None = None,
                    max_pixels: int = 1_500_000, side: str = "both",
                    ) -> tuple[Tensor, Tensor | None, tuple[float, float]]:
    """`estimate_depth`'s door: its arguments' types, dtypes and shapes, the depth range and
    the pixels (one pass over each photo, skipped inside `optics.checks.values_checked`, where
    the caller has read them), each refused in one line that names the argument; returns the
    photos, float16 and bfloat16 ones widened to float32, and `(near, far)` as floats. Code
    behind the door takes these values as they are.

    Example:
        >>> check_arguments(torch.zeros(2, 3, 8, 8, dtype=torch.uint8), None, (1.0, 5.0))
        Traceback (most recent call last):
        ...
        TypeError: focused must hold floating-point linear intensity in [0, 1], got dtype torch.uint8; convert it with .float() / 255 (and decode sRGB: kornia.color.rgb_to_linear_rgb)
    """
    photos = [_photo(name, photo) for name, photo in (("focused", focused), ("image", image))]
    for name, value in (("settings", settings), ("image_settings", image_settings)):
        given = value is not None or name == "settings" and len(photos[0]) > 0
        if given and not (isinstance(value, CameraSettings) and
                                      (not value.is_batched or value.shape[0] == 1)):
            raise (ValueError(f"{name} must be one scene's (F,) settings, got shape "
                              f"{tuple(value.shape)} (a batch of {value.shape[0]} scenes); "
                              f"estimate_depth takes one scene: give {name}[i]")
                   if isinstance(value, CameraSettings) else
                   TypeError(f"{name} must be an optics.CameraSettings, got "
                             f"{type(value).__name__}; build one with CameraSettings("
                             "focal_length, f_number, focus_distance, pixel_pitch)"))
    if isinstance(depth_range, (str, bytes)) or not hasattr(depth_range, "__len__") or \
            len(depth_range) != 2 or not all(_is_number(d) for d in depth_range):
        raise TypeError(f"depth_range must be two numbers (near, far) in metres, got "
                        f"{depth_range!r}")
    near, far = (float(d) for d in depth_range)
    focal = None if settings is None else float(settings.focal_length.max())
    problem = None if is_tracing() else depth_range_problem(near, far, focal)
    refuse_broken([
        (photos[1] is not None and photos[0].shape[-2:] != photos[1].shape[-2:], lambda:
         f"focused photos are {tuple(photos[0].shape[-2:])} pixels but the all-in-focus photo "
         f"is {tuple(photos[1].shape[-2:])}"),
        (image_settings is not None and (photos[1] is None or settings is None
                                         or image_settings.n_shots != 1), lambda:
         "image_settings are the settings of image, as one more shot: give image, the focused "
         f"photos' settings and image_settings of 1 shot, got {image_settings.n_shots} shot(s)"),
        ((max_coc_px is not None and not (math.isfinite(max_coc_px) and max_coc_px > 0))
         or not max_pixels >= 64, lambda: "max_coc_px must be a positive number of pixels (or "
         f"None) and max_pixels >= 64 (8x8 pixels), got max_coc_px={max_coc_px!r}, "
         f"max_pixels={max_pixels!r}"),
        (problem is not None, lambda: f"depth_range {problem}, got {tuple(depth_range)!r}"),
        (side not in SIDES, lambda: f"side must be one of {SIDES}, got {side!r}"),
        (side != "both" and len(focus_planes(settings, image_settings)) != 1, lambda:
         f"side={side!r} states where the scene lies about one focus plane, but the shots are "
         f"focused at {', '.join(f'{d:g}' for d in focus_planes(settings, image_settings))} m: "
         "give side='both' (shots focused at several distances tell near from far)")])
    return photos[0], photos[1], (near, far)


def depth_range_problem(near: float, far: float, focal_length: float | None = None
                        ) -> str | None:
    """Why `(near, far)` metres is no depth range (for a lens of `focal_length` metres), or
    None: it must be finite with 0 < near < far <= `MAX_FAR_M`, beyond the focal length.

    Example:
        >>> depth_range_problem(1.0, 10.0) is None, depth_range_problem(0.01, 10.0, 0.05)
        (True, 'must lie beyond the focal length (0.05 m)')
    """
    if not (math.isfinite(near) and math.isfinite(far) and 0 < near < far):
        return "must be finite metres (near, far) with 0 < near < far"
    if far > MAX_FAR_M:
        return (f"far end must be at most {MAX_FAR_M:g} metres (beyond it every lens blurs as "
                "at infinity)")
    if focal_length is not None and near <= focal_length:
        return f"must lie beyond the focal length ({focal_length:g} m)"
    return None


def _photo(name: str, photo: Any) -> Tensor | None:
    """The photo `name` checked (`check_arguments`): a floating-point tensor, `(F,3,H,W)` for
    `focused`, `(3,H,W)` for `image` (the size of `focused`), finite linear intensity."""
    if photo is None and name == "image":
        return None
    if not isinstance(photo, Tensor) or not photo.is_floating_point():
        raise TypeError(f"{name} must be a torch.Tensor, got {type(photo).__name__}"
                        if not isinstance(photo, Tensor) else
                        f"{name} must hold floating-point linear intensity in [0, 1], got "
                        f"dtype {photo.dtype}; convert it with .float() / 255 (and decode "
                        "sRGB: kornia.color.rgb_to_linear_rgb)")
    check_shape(name, photo, ["F", "3", "H", "W"] if name == "focused" else ["3", "H", "W"])
    if photo.numel() and not is_tracing(photo):  # one pass: NaN fails every comparison
        low, high = (float(v) for v in torch.aminmax(photo.detach()))
        if not MIN_INTENSITY <= low <= high <= MAX_INTENSITY:
            check_finite(name, photo)
            hint = ("; 8-bit values? divide by 255 (16-bit: 65535) and decode sRGB "
                    "(kornia.color.rgb_to_linear_rgb)" if high > MAX_INTENSITY else "")
            raise ValueError(f"{name} must hold linear intensity in [0, 1], got values from "
                             f"{low:.4g} to {high:.4g}{hint}")
    return photo.float() if photo.dtype in _WIDENED else photo


def _method_object(method: str, model: nn.Module | None, options: Mapping[str, Any] | None,
                   progress: bool, has_image: bool, n_shots: int) -> nn.Module:
    """`model`, or the method named `method` (`"auto"`: `choose_method`) built with `options`."""
    if model is None and method == "auto":
        method = choose_method(has_image, n_shots)
    if model is None and method in METHODS:
        return METHODS[method](progress=progress, **dict(options or {}))
    if model is None or options:
        raise ValueError(f"method must be 'auto' or one of {sorted(METHODS)}, got {method!r}"
                         if model is None else
                         "options configure a method by name; give them to the model's class "
                         f"instead (got model={type(model).__name__} and options={dict(options)})")
    return model


def _run_native(model: nn.Module, image: Tensor, focused: Tensor,
                settings: CameraSettings | None, near: float, far: float,
                all_in_focus: bool) -> dict[str, Any]:
    """Run a method that reads the photos at their own resolution (a trained network)."""
    shots = None if settings is None else settings.to(focused.dtype)
    out = model(image[None], focused[None], shots, near, far)
    confidence = out.get("confidence")
    result = {"depth": out["depth"][0], "confidence": None if confidence is None
              else confidence[0], "depth_range": getattr(model, "depth_range", (near, far)),
              "mirrored_depths": None}
    if all_in_focus:
        result["all_in_focus"] = image
    return result


def _refuse_unreadable(model: nn.Module, image: Tensor | None, focused: Tensor,
                       settings: CameraSettings, near: float, far: float) -> None:
    """Refuse photos a depth-from-defocus method cannot read: no all-in-focus photo where it
    needs one, too few shots, or shots that do not tell depths in `[near, far]` apart."""
    if image is None and getattr(model, "needs_image", True) or len(focused) < 1 + (image is None):
        raise ValueError(f"{type(model).__name__} needs an all-in-focus photo: give image"
                         if image is None and getattr(model, "needs_image", True) else
                         f"{type(model).__name__} reads depth from defocus: give 1 or more "
                         "focused photos with an all-in-focus image, or 2 or more, each "
                         f"focused elsewhere, without one (got {len(focused)})")
    if image is None:
        check_shots_differ(settings, near, far)
    else:
        check_blur_readable(settings, near, far)


def _fused(focused: Tensor, out: Mapping[str, Any], align: bool) -> Tensor:
    """The all-in-focus image fused from the shots by the blur each has at the depth found."""
    motions = torch.cat([out["shifts"], out["zooms"][:, None],
                         torch.deg2rad(out["rotations"])[:, None]], 1)
    return fuse_all_in_focus(focused, out["blur"], motions if align else None)
