"""Depth of your own photos (`defocus predict`): read the photos and the camera, pick the method,
run `models.estimate_depth` and write the results.

The camera comes from the options, a camera JSON written by `defocus calibrate` or the photos'
EXIF (`optics.resolve_settings`). Without a model file the label-free methods run (no network, any
camera): the sweep over depth with an all-in-focus photo, the relative blur between the focused
photos without one, or depth from focus of a stack; with a model file (`models.load_depth_model`)
that network.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import torch

from datasets.photos import CameraFile
from defocus.app import silent
from defocus.options import check_positive
from optics.checks import values_checked

from .outputs import OutputPlan, plan_files

Report = Callable[[str], None]
#: Below this confidence a pixel's depth is not to be trusted (the summary counts them).
LOW_CONFIDENCE = 0.2


@dataclasses.dataclass
class PredictRequest:
    """What to predict from (the options of `defocus predict`, lengths in metres)."""

    focused: list[Path] = dataclasses.field(default_factory=list)
    image: Path | None = None
    checkpoint: Path | None = None
    image_f_number: float | None = None
    image_focus_distance: float | None = None
    method: str = "auto"
    #: camera values the user gave (`focus_distance`, `f_number` per photo, `focal_length`,
    #: `pixel_pitch`), before the camera JSON and the EXIF (`optics.resolve_settings`)
    camera_options: dict[str, Any] = dataclasses.field(default_factory=dict)
    linear: bool = False
    camera: Path | None = None
    depth_range: tuple[float, float] | None = None
    aggregation: str = "semi-global"
    #: where the scene lies about the shots' one focus plane: "beyond", "before" or "both"
    side: str = "both"
    device: str = "auto"
    out: Path = Path("runs/predict")
    #: show progress bars
    progress: bool = True
    #: replace the results of an earlier run in `out` (`defocus.app.outputs`)
    overwrite: bool = False


@dataclasses.dataclass
class Photos:
    """The photos as read: the all-in-focus one (or None), the focused stack `(F,3,H,W)` (the
    all-in-focus photo alone where there are no focused ones) and the metadata of each."""

    image: torch.Tensor | None
    focused: torch.Tensor
    image_info: Any
    infos: list[Any]
    first_path: Path
    #: the `--focused` files, in their order
    focused_paths: list[Path] = dataclasses.field(default_factory=list)


#: The largest depth depth_mm.png holds, millimetres (16 bits).
MAX_DEPTH_MM = 65535
#: The files `predict` writes under `out`, and what each holds.
OUTPUT_FILES = {"depth.npy": "depth map", "depth_mm.png": "depth map in millimetres",
                "depth.png": "depth preview",
                "confidence.png": "confidence map", "all_in_focus.png": "all-in-focus photo",
                "figure.png": "figure"}


def plan_outputs(request: PredictRequest) -> OutputPlan:
    """The checked plan of `predict`'s outputs (`OUTPUT_FILES` under `--out`): none is an input
    photo, the camera JSON or the model file, none replaces an earlier result without
    `--overwrite` (`defocus.app.outputs`)."""
    inputs = [("--image", request.image), *(("--focused", p) for p in request.focused),
              ("--camera", request.camera), ("model file", request.checkpoint)]
    return plan_files(Path(request.out), OUTPUT_FILES, request.overwrite, inputs)[0]


#: The options of `PredictRequest` that hold lengths or f-numbers: finite numbers > 0.
POSITIVE_OPTIONS = ("image_f_number", "image_focus_distance", "depth_range")


def check_request(request: PredictRequest) -> None:
    """`predict`'s door: refuse option values and combinations that cannot work, before
    anything is read, in one line naming the option (`request_problem`); the numbers must be
    finite and > 0 (`defocus.options.check_positive`). What passes is not checked again:
    `predict` runs `estimate_depth` with its value checks off
    (`optics.checks.values_checked`)."""
    check_positive(request, *POSITIVE_OPTIONS)
    check_positive(SimpleNamespace(**request.camera_options), *request.camera_options)
    problem = request_problem(request)
    if problem is not None:
        raise ValueError(problem)


def request_problem(request: PredictRequest) -> str | None:
    """Why `request` cannot work, or None: an unknown `--device`, `--aggregation` or
    `--method`, a `--depth-range` that is not NEAR < FAR metres
    (`models.depth_from_photos.depth_range_problem`), too few photos, or options that do not
    go together."""
    from models.depth_from_photos import METHODS, depth_range_problem
    from models.depth_from_photos.cost_volume import AGGREGATIONS
    from models.devices import check_device

    try:
        check_device(request.device)
    except ValueError as error:
        return f"--device: {error}"
    model, image, n_focused = request.checkpoint, request.image, len(request.focused)
    rules = (
        (request.aggregation not in AGGREGATIONS, lambda: "--aggregation must be one of "
         f"{', '.join(AGGREGATIONS)}, got {request.aggregation!r}"),
        (request.method not in ("auto", *METHODS), lambda: "--method must be auto or one of "
         f"{', '.join(METHODS)}, got {request.method!r}"),
        (model is not None and (request.aggregation != "semi-global" or request.method != "auto"),
         lambda: "--aggregation and --method choose how the label-free methods work: give "
         f"them without a model file (got {model})"),
        (image is None and (model is not None or n_focused < 2), lambda: "give --image (an "
         "all-in-focus photo), or 2 or more --focused photos focused at different distances "
         f"(got {n_focused})"),
        (request.depth_range is not None and depth_range_problem(*request.depth_range)
         is not None, lambda: "--depth-range {:g} {:g}: ".format(*request.depth_range)
         + depth_range_problem(*request.depth_range)),
        (image is None and request.method == "sweep", lambda: "--method sweep compares the "
         "focused photos with an all-in-focus photo: give --image"),
        (model is None and n_focused == 0, lambda: "depth from defocus needs --focused photos "
         "(2 or more, each focused at its own --focus-distance)"),
    )
    return next((message() for broken, message in rules if broken), None)


def check_inputs_exist(request: PredictRequest) -> None:
    """Refuse a photo, camera JSON or model file that is missing, naming it: the inputs are
    checked before the outputs, so that a wrong path is not answered by an earlier run's
    files."""
    from datasets.io import require_file

    for path, what in ((request.image, "a photo"), *((p, "a photo") for p in request.focused),
                       (request.camera, "a camera JSON"), (request.checkpoint, "a model file")):
        if path is not None:
            require_file(Path(path), what)


def check_beyond_lens(request: PredictRequest, settings, depth_range) -> None:
    """Refuse a `--depth-range` or `--image-focus-distance` within the focal length (nothing
    there is imaged on the sensor)."""
    focal = float(settings.focal_length.max())
    for option, value in (("--depth-range", depth_range[0]),
                          ("--image-focus-distance", request.image_focus_distance)):
        if value is not None and value <= focal:
            raise ValueError(f"{option} must lie beyond the focal length ({focal:g} m): got "
                             f"{'NEAR ' if option == '--depth-range' else ''}{value:g} m")


def apply_camera_policy(request: PredictRequest, camera: CameraFile | None, has_model: bool,
                        report: Report = silent) -> None:
    """Where the camera JSON was fitted with references that were not sharp
    (`reference_f_number`, e.g. f/8 beside f/2.8), `--image` counts as such a shot; then the
    options about `--image` are checked."""
    check_photo_order(request, None if camera is None else camera.photos)
    reference = None if camera is None else camera.reference_f_number
    if request.image is not None and request.image_f_number is None and not has_model \
            and request.method in ("auto", "relative-blur") and reference is not None:
        request.image_f_number = float(reference)
        report(f"--image counts as an f/{request.image_f_number:g} shot (reference_f_number "
               f"of {request.camera}); --method sweep takes it as all-in-focus instead")
    shot = request.image_f_number is not None
    if request.image_focus_distance is not None and not shot or shot and (
            request.image is None or has_model or request.method in ("sweep", "focus")):
        raise ValueError("--image-f-number makes --image one more shot of the relative blur "
                         "(--image-focus-distance goes with it): give --image, no model "
                         "file, and --method auto or relative-blur")


def check_photo_order(request: PredictRequest, listed: Any) -> None:
    """Refuse `--focused` photos that are the ones the camera JSON's `"photos"` list names
    (by file name) in another order: its per-shot settings would go to the wrong photos."""
    if listed is None:  # (the camera file checked its names)
        return
    given = [path.name for path in request.focused]
    listed = [Path(name).name for name in listed]
    if given != listed and sorted(given) == sorted(listed):
        raise ValueError(f"--focused gives {', '.join(given)} but {request.camera} holds the "
                         f"settings of {', '.join(listed)} in that order (its \"photos\"): "
                         "give the photos in that order")


def read_photos(request: PredictRequest) -> Photos:
    """Read `--image` and the `--focused` photos: one size, none identical to another, none
    without texture (`datasets.photos.check_photo_content`). The focused photos are decoded
    straight into their stack (`read_photo(into=...)`): no second copy of any photo."""
    from datasets.photos import read_photo

    encoding = "linear" if request.linear else "srgb"
    image, image_info = read_photo(request.image, encoding=encoding) if request.image \
        else (None, None)
    named = [] if image is None else [("--image", request.image, image)]
    _check_photo(named, 0)
    stack: list[torch.Tensor] = []

    def slot(index: int, path: Path):
        def allocate(size: tuple[int, int]) -> torch.Tensor:
            first_path, first = named[0][1:] if named else (path, None)
            if first is not None and tuple(first.shape[-2:]) != tuple(size):
                raise ValueError(f"{path} is {tuple(size)} pixels but {first_path} is "
                                 f"{tuple(first.shape[-2:])}; all photos must have one size")
            if not stack:
                stack.append(torch.empty((len(request.focused), 3, *size)))
            return stack[0][index]
        return allocate

    infos = []
    for index, path in enumerate(request.focused):
        infos.append(read_photo(path, encoding=encoding, into=slot(index, path))[1])
        named.append(("--focused", path, stack[0][index]))
        _check_photo(named, len(named) - 1)
    # without focused photos only a network that reads the all-in-focus photo alone runs
    focused = stack[0] if stack else image[None]
    return Photos(image, focused, image_info, infos, named[0][1], list(request.focused))


def _check_photo(named: list[tuple[str, Path, torch.Tensor]], index: int) -> None:
    """Refuse photo `index` of `named` (`(option, path, photo)`) without texture or the same
    as an earlier one."""
    from datasets.photos import check_photo_content

    if index >= len(named):
        return
    option, path, photo = named[index]
    check_photo_content(photo, f"{option} {path}")
    for other_option, other, earlier in named[:index]:
        # --image may name a --focused file itself (that shot then also serves as the sharp
        # one, as before); any other pair of identical shots is refused
        if other_option != option and Path(other) == Path(path):
            continue
        if torch.equal(photo, earlier):
            raise ValueError(f"{option} {path} is the same photo as {other_option} {other}: "
                             "two identical shots have no defocus between them to read; "
                             "give photos focused at different distances")


def depth_range_of(request: PredictRequest, model: Any, n_photos: int) -> tuple[float, float]:
    """The depth range: `--depth-range` for the label-free methods, a trained network's own."""
    from models.depth_from_photos import TrainedNetwork

    if model is None or not isinstance(model, TrainedNetwork):
        if not n_photos or request.depth_range is None:
            raise ValueError("depth from defocus needs --focused photos (2 or more, each "
                             "focused at its own --focus-distance)" if not n_photos else
                             "give --depth-range NEAR FAR (metres): the thin lens has two "
                             "depths for each blur, the range picks the right one")
        return tuple(request.depth_range)
    if model.input_mode == "aif+focused" and n_photos != model.n_focus:
        raise ValueError(f"this network needs {model.n_focus} --focused photos, got {n_photos}")
    return model.depth_range


def warn_other_camera(model: Any, settings) -> None:
    """Warn in one line where a network trained for one camera reads photos of another
    (`models.depth_from_photos.trained_network.camera_mismatch`): its depth is then likely
    wrong."""
    from models.depth_from_photos import TrainedNetwork
    from models.depth_from_photos.trained_network import camera_mismatch

    if isinstance(model, TrainedNetwork) and model.input_mode == "aif+focused" \
            and settings is not None:
        problem = camera_mismatch(model.camera, settings)
        if problem is not None:
            warnings.warn(problem, stacklevel=2)


def image_shot_settings(request: PredictRequest, settings):
    """The settings of `--image` as one more shot (`--image-f-number`), else None."""
    if request.image_f_number is None:
        return None
    focus = request.image_focus_distance or float(settings.focus_distance.reshape(-1)[0])
    return settings.select_shots([0]).replace(
        f_number=torch.tensor([request.image_f_number], dtype=torch.float64),
        focus_distance=torch.tensor([focus], dtype=torch.float64))


def predict(request: PredictRequest, report: Report = silent) -> dict[str, Any]:
    """Run `defocus predict`'s whole job and write its outputs under `request.out`; returns
    `estimate_depth`'s result with `written` (the files), `removed` (the files of an earlier
    run that this one does not write, removed under `--overwrite` so that the folder holds one
    run) and `method` added.

    Example:
        >>> out = predict(PredictRequest([Path("near.jpg"), Path("far.jpg")],
        ...                              depth_range=(0.5, 5.0)))  # doctest: +SKIP
    """
    from models import estimate_depth, load_depth_model
    from models.devices import select_device

    check_request(request)
    check_inputs_exist(request)  # the inputs before the outputs
    plan = plan_outputs(request)  # before any work: nothing is lost, nothing refused late
    device = select_device(request.device)
    # the model first: a file that is no model is refused before any photo is read
    model = None if request.checkpoint is None else load_depth_model(request.checkpoint, device)
    camera = None if request.camera is None else CameraFile.read(
        request.camera, n_shots=len(request.focused),
        shots=f"--focused gives {len(request.focused)} photo(s)",
        given=[name for name, value in request.camera_options.items() if value not in (None, [])])
    apply_camera_policy(request, camera, model is not None, report)
    calibration = None if camera is None else camera.settings
    photos = read_photos(request)
    settings = _settings(request, photos, calibration, report)
    warn_other_camera(model, settings)
    depth_range = depth_range_of(request, model, len(photos.infos))
    if settings is not None:
        check_beyond_lens(request, settings, depth_range)
    image_settings = image_shot_settings(request, settings)
    method, options = _method(request, model, photos, image_settings)
    with values_checked():  # checked at this door: the options, and each photo once on reading
        out = estimate_depth(photos.focused.to(device), settings, depth_range,
                             image=None if photos.image is None else photos.image.to(device),
                             image_settings=image_settings, method=method, model=model,
                             options=options, progress=request.progress, side=request.side)
    if image_settings is not None:
        report(f"--image is one more shot: f/{request.image_f_number:g}, focused at "
               f"{float(image_settings.focus_distance[0]):g} m")
    if "shifts" in out:
        infos = ([] if photos.image_info is None else [photos.image_info]) + photos.infos
        _report_working_resolution(out, depth_range, infos, method, report)
    out["method"] = method
    out["low_confidence"] = None if out["confidence"] is None else \
        float((out["confidence"] < LOW_CONFIDENCE).float().mean())
    out["written"] = write_outputs(request.out, out, photos, plan, None if settings is None
                                   else settings.focus_distance.reshape(-1).tolist())
    out["removed"] = [path.name for path in plan.removed]
    return out


def _settings(request: PredictRequest, photos: Photos, calibration, report: Report):
    from datasets.photos import describe_settings, resolve_settings

    if not photos.infos:
        return None
    settings, sources = resolve_settings(photos.infos, request.camera_options, calibration)
    report(describe_settings(settings, sources))
    return settings


def _method(request: PredictRequest, model, photos: Photos, image_settings):
    """The method to run and its options."""
    from models.depth_from_photos import choose_method

    method = request.method if request.method != "auto" or model is not None \
        else choose_method(photos.image is not None and image_settings is None,
                           len(photos.infos) + (image_settings is not None))
    options = {"aggregation": request.aggregation} if method in ("sweep", "relative-blur") \
        and model is None else None
    return method, options


def _report_working_resolution(out, depth_range, infos, method, report: Report) -> None:
    from datasets.photos import compression_warning

    near, far = depth_range
    moved = ", ".join(f"({dy:+.1f}, {dx:+.1f}, x{zoom:.4f}, {turn:+.2f} deg)"
                      for (dy, dx), zoom, turn in zip(out["shifts"].tolist(), out["zooms"].tolist(),
                                                      out["rotations"].tolist(), strict=True))
    swept = out["depth_range"]
    if tuple(swept) != (near, far):
        report(f"the scene lies within {swept[0]:.2f}-{swept[1]:.2f} m of the stated "
               f"{near:g}-{far:g} m: depth computed again over that range, at a finer resolution")
    onto = "the all-in-focus photo" if method == "sweep" else "the first"
    report(f"method {method}; working resolution {out['scale']:.3f} x the photos; focused photos "
           f"aligned onto {onto}: moved by {moved} (pixels down, right; magnification; "
           "rotation, clockwise)")
    jpeg = compression_warning(infos, out["scale"])
    if jpeg is not None:
        warnings.warn(jpeg, stacklevel=1)


def panel_titles(photos: Photos, focus_distances: list[float] | None = None,
                 ) -> tuple[str, list[str] | None]:
    """The titles of figure.png's photo panels: the `--image` file's name (else "all-in-focus
    (fused)") and each focused photo's file name with its focus distance, metres.

    Example:
        >>> photos = Photos(None, torch.zeros(2, 3, 4, 4), None, [{}, {}], Path("n.png"),
        ...                 [Path("n.png"), Path("f.png")])
        >>> panel_titles(photos, [2.3, 4.6])
        ('all-in-focus (fused)', ['n.png, focused at 2.3 m', 'f.png, focused at 4.6 m'])
    """
    image = "all-in-focus (fused)" if photos.image is None else photos.first_path.name
    if not photos.infos or len(photos.focused_paths) != len(photos.focused):
        return image, None
    distances = focus_distances or [None] * len(photos.focused_paths)
    return image, [path.name if distance is None else f"{path.name}, focused at {distance:.3g} m"
                   for path, distance in zip(photos.focused_paths, distances, strict=True)]


def write_outputs(folder: Path, out: dict[str, Any], photos: Photos,
                  plan: OutputPlan | None = None,
                  focus_distances: list[float] | None = None) -> list[str]:
    """Write depth.npy (metres), depth_mm.png (16-bit millimetres), depth.png (a
    colour-mapped preview with a scale in metres), confidence.png, all_in_focus.png and
    figure.png (each photo panel titled by `panel_titles`, with the focused photos'
    `focus_distances`; the depths that may lie mirrored across the focus plane,
    `out["mirrored_depths"]`, hatched) under `folder`,
    each whole or not at all, through `plan`
    (by default one that replaces no earlier result, `defocus.app.outputs`); an earlier run's
    file of `OUTPUT_FILES` that this run does not write (confidence.png where the method gives
    no confidence) is removed (`plan.removed`); returns the names written."""
    import numpy as np
    from PIL import Image

    from datasets.photos import save_photo
    from models.plotting import (
        PNG_COMPRESS_LEVEL,
        plot_prediction,
        robust_range,
        save_depth_preview,
    )

    depth = out["depth"].cpu()
    confidence = None if out["confidence"] is None else out["confidence"].cpu()
    if not bool(torch.isfinite(depth).all()):
        raise ValueError("the prediction is not finite; nothing written")
    plan = plan or plan_files(Path(folder), OUTPUT_FILES, overwrite=False)[0]
    folder = Path(folder)
    millimetres = np.round(depth[0].numpy() * 1000)
    beyond = float((millimetres > MAX_DEPTH_MM).mean())
    if beyond:
        warnings.warn(f"{beyond:.1%} of the depth lies beyond {MAX_DEPTH_MM / 1000:g} m, the "
                      f"farthest depth_mm.png holds: it reads {MAX_DEPTH_MM} there (depth.npy "
                      "holds every depth)", stacklevel=2)
    millimetres = np.clip(millimetres, 0, MAX_DEPTH_MM).astype(np.uint16)
    fused = out["all_in_focus"].cpu()
    files = {"depth.npy": lambda path: np.save(path, depth[0].numpy().astype(np.float32)),
             "depth_mm.png": lambda path: Image.fromarray(millimetres).save(
                 path, compress_level=PNG_COMPRESS_LEVEL),
             "depth.png": lambda path: save_depth_preview(path, depth[0], robust_range(depth))}
    if confidence is not None:
        files["confidence.png"] = lambda path: Image.fromarray(
            (confidence[0].clamp(0, 1).numpy() * 255).astype(np.uint8)).save(
                path, compress_level=PNG_COMPRESS_LEVEL)
    files["all_in_focus.png"] = lambda path: save_photo(path, fused)
    image_title, focused_titles = panel_titles(photos, focus_distances)
    files["figure.png"] = lambda path: plot_prediction(
        path, fused, depth, photos.focused if photos.infos else None,
        stated_range=tuple(out["depth_range"]), confidence=confidence,
        image_label=image_title, focused_labels=focused_titles,
        mirrored_depths=out.get("mirrored_depths"),
        side=None if "side" not in out else (out["side"], out["focus_plane"]),
        off_side=out.get("off_side"))
    # the encoders of the plain images (numpy, zlib, Pillow: they release the GIL) run in a
    # second thread beside the matplotlib ones
    with plan.writing(remove_unwritten=True) as write, ThreadPoolExecutor(1) as encoder:
        jobs = [encoder.submit(write, folder / name, writer) for name, writer in files.items()
                if name in PLAIN_IMAGES]
        for name, writer in files.items():
            if name not in PLAIN_IMAGES:
                write(folder / name, writer)
        for job in jobs:
            job.result()
    return [name for name in files if name != "figure.png"]


#: The outputs `write_outputs` encodes without matplotlib.
PLAIN_IMAGES = frozenset({"depth.npy", "depth_mm.png", "confidence.png", "all_in_focus.png"})
