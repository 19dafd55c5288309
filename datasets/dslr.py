"""DSLR aperture pairs of Carvalho et al. 2018 ("DFD-indoor"): real f/2.8 and f/8 photos, depth.

The release layout (the authors' `dfd_datasets/dfd_indoor`, read as it is)::

    <root>/dfd_dataset_indoor_N2_8/rgb/<split>/<time>.JPG     f/2.8 photos (the defocused ones)
    <root>/dfd_dataset_indoor_N8/rgb/<split>/<time>.JPG       f/8 photos, same file names
    <root>/dfd_dataset_indoor_N2_8/depth/<split>/<time>.png   16-bit depth, millimetres, 0 = unknown

`<time>` is an ISO time stamp (`2018-04-26T16:38:31.689710`). A depth file carries the depth
sensor's own time stamp, a fraction of a second to a few seconds from the photos' one: each photo
is paired with the depth file *nearest in time* (never by sorted position), within `max_gap_s`
seconds, and no depth file serves two photos. The f/8 photo of a scene has the f/2.8 photo's file
name (else it too is paired by nearest time).

The older flat layout (`<root>/<split>/{f2.8,f8,depth}/<name>.png|jpg`, paired by name) is read
too.

Two ways to read a scene (`focus`): `"real"` (the default) gives the real f/2.8 photo as the
focused image; `"synthesized"` reads the set the paper's way (Gur & Wolf 2019), as an RGB-D
set: the f/8 photo is the all-in-focus image and the focused images are rendered from it and
the registered depth through the PSF layer at the paper's two focus settings,
`datasets.focus.PAPER_FOCUS_FRACTIONS` of the depth cap (2 m and 8 m of 10 m), with the DSLR
camera (35 mm, the f-number and pixel pitch of the preset or of `camera=`). Photos are 8- or 16-bit sRGB PNG or JPEG, decoded to linear intensity. The f/2.8 photo is the
real focused image; the f/8 photo is the `image` (nearly, not fully, in focus: its own blur is
about `2.8 / 8` of the f/2.8 one, `reference_f_number`). The camera is `datasets.presets.DSLR`
(35 mm, f/2.8, focus 1.7 m, the full-frame pitch scaled to the stored width), or a camera JSON
(`camera=`) such as `defocus calibrate --data dslr` writes (`datasets.calibration`).
"""

from __future__ import annotations

from datetime import datetime
from pathlib import Path
from typing import Any

import torch

from optics import CameraSettings

from .base import DepthDataset
from .depth import fill_unknown, require_valid_depth, valid_depth_mask
from .focus import PAPER_FOCUS_FRACTIONS, CameraPreset, paper_focus
from .io import read_depth_png, require_args, require_one_size, require_root
from .pairs import register_focused, relative_pair
from .photos import CameraFile, read_photo, settings_for_shots
from .presets import DSLR as DSLR_PRESET

#: Folder of the release holding the f/2.8 photos and the depth.
WIDE_FOLDER = "dfd_dataset_indoor_N2_8"
#: Folder of the release holding the f/8 photos.
REFERENCE_FOLDER = "dfd_dataset_indoor_N8"
PHOTO_SUFFIXES = (".png", ".jpg", ".jpeg")
#: How the focused images are read (`DSLR(focus=...)`): the real f/2.8 photo, or synthesised.
FOCUS_MODES = ("real", "synthesized")
#: What the scenes have, for the error on a camera of several shots.
ONE_SHOT = "a DSLR scene has one focused (f/2.8) photo"
LAYOUT = (
    "  <root>/dfd_dataset_indoor_N2_8/rgb/<split>/<time>.JPG    (f/2.8 photos)\n"
    "  <root>/dfd_dataset_indoor_N8/rgb/<split>/<time>.JPG      (f/8 photos)\n"
    "  <root>/dfd_dataset_indoor_N2_8/depth/<split>/<time>.png  (16-bit depth, mm, 0 = unknown)\n"
    "or the flat layout <root>/<split>/{f2.8,f8,depth}/<name>.png|jpg"
)


def time_stamp(path: Path) -> float | None:
    """Seconds since the epoch of a file named by an ISO time stamp, else None.

    Example:
        >>> time_stamp(Path("2018-04-26T16:38:31.5.png")) - time_stamp(Path("2018-04-26T16:38:31.png"))
        0.5
        >>> time_stamp(Path("scene00.png")) is None
        True
    """
    try:
        return datetime.fromisoformat(path.stem).timestamp()
    except ValueError:
        return None


def pair_files(photos: list[Path], candidates: list[Path], what: str,
               max_gap_s: float) -> list[Path]:
    """For each photo, its file among `candidates`: the same stem, else the nearest in time.

    Args:
        photos: the photos to pair (file names are time stamps or plain names).
        candidates: the files to pair them with.
        what: what a candidate is, for error messages (e.g. `"depth file"`).
        max_gap_s: the largest time difference, seconds, of a pair by time.

    Returns:
        one candidate per photo, in the photos' order.

    Raises:
        FileNotFoundError: a photo has no candidate of its name or within `max_gap_s` seconds
            (the message names the photo and the nearest candidate), or two photos would share
            one candidate.

    Example:
        >>> photos = [Path("2018-01-01T10:00:00.JPG"), Path("2018-01-01T10:01:00.JPG")]
        >>> depth = [Path("2018-01-01T10:01:00.4.png"), Path("2018-01-01T09:59:59.8.png")]
        >>> pairs = pair_files(photos, depth, "depth file", 5.0)
        >>> pairs[0].name, pairs[1].name
        ('2018-01-01T09:59:59.8.png', '2018-01-01T10:01:00.4.png')
    """
    by_stem = {p.stem: p for p in candidates}
    timed = [(t, p) for p in candidates if (t := time_stamp(p)) is not None]
    pairs, owner = [], {}
    for photo in photos:
        match = by_stem.get(photo.stem)
        stamp = time_stamp(photo)
        if match is None and stamp is not None and timed:
            gap, match = min(((abs(t - stamp), p) for t, p in timed), key=lambda x: x[0])
            if gap > max_gap_s:
                raise FileNotFoundError(
                    f"{str(photo)!r} has no {what} within {max_gap_s:g} s (the nearest, "
                    f"{str(match)!r}, is {gap:.1f} s away)")
        if match is None:
            suffix = candidates[0].suffix if candidates else ".png"
            expected = _folder(candidates, photo) / (photo.stem + suffix)
            raise FileNotFoundError(f"missing file {str(expected)!r}: the {what} of "
                                    f"{str(photo)!r} (same name, or a time stamp near it)")
        if match in owner:
            raise FileNotFoundError(f"{str(photo)!r} and {str(owner[match])!r} both pair with "
                                    f"the {what} {str(match)!r}: one is missing its own")
        owner[match] = photo
        pairs.append(match)
    return pairs


def _folder(candidates: list[Path], photo: Path) -> Path:
    return candidates[0].parent if candidates else photo.parent


def _files(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in suffixes)


class DSLR(DepthDataset):
    """Real defocus: the f/8 photo as `image`, the f/2.8 photo as the one focused image.

    Args:
        root: dataset folder (the release's `dfd_indoor`, or the flat layout).
        split: `"train"` or `"test"`.
        depth_scale: metres per stored depth unit (`1e-3`: millimetres).
        sensor_width_px: width in pixels of the full sensor whose pitch the preset gives (the
            Nikon D810 records 7360); the effective pitch is scaled by this over the photo width.
        wide: sub-folder of the wide-open photos (flat layout).
        reference: sub-folder of the f/8 reference photos (flat layout).
        depth: sub-folder of the depth PNGs (flat layout).
        preset: the camera of the wide photo (`datasets.presets.DSLR` by default).
        camera: a camera JSON (`defocus calibrate --data dslr`) or settings for
            the wide photos at the stored resolution, replacing the preset; a JSON's
            `reference_f_number` sets `reference_f_number`. Values per shot must be one
            (the scenes' one focused photo): a list of different values is refused by name
            (`datasets.photos.camera_file`), never cut to its first value.
        max_gap_s: the largest time difference, seconds, of a photo and its depth file.
        scenes: keep only these scenes (indices or a slice of the split in time order, e.g.
            `slice(0, 61)` for training and `slice(61, None)` for validation).
        relative: samples whose camera is the blur *from* `image` *to* `focused`, for training
            through the renderer: the f/8 photo's own blur taken out of the f-number
            (`N / sqrt(1 - (N / N_ref)^2)`, exact for Gaussian PSFs) and `image` blurred by the
            camera JSON's `focus_floor_px` (the blur the f/2.8 photos have even in focus, which
            no depth explains), and scaled by its `exposure_gain` (`datasets.pairs.relative_pair`).
            Off, the camera is the lens's own (for `estimate_depth` with the f/8 photo as a shot).
        register: move the f/2.8 photo onto the f/8 one (`datasets.pairs.register_focused`):
            the shots of a scene are 0.3 to 4 pixels apart, which a loss through the renderer
            reads as blur. Default: on for `relative` samples (training), off otherwise
            (`estimate_depth` and the calibration register the photos themselves).
        focus: `"real"`: the f/2.8 photo is the focused image; `"synthesized"`: the f/8 photo
            is the all-in-focus image and two focused images are rendered from it and the depth
            (module docstring) with the camera's focal length, f-number and pixel pitch (of
            the preset or `camera`; its focus distance, floor and exposure gain are not used).
            The f/2.8 photo is then not read; `relative` and `register` do not apply.
        focus_fractions: with `focus="synthesized"`, where the focused images are focused:
            fractions of the preset's depth cap, one per image (the paper's 0.2 and 0.8 by
            default; one fraction gives the real pairs' situation, one focus plane).
        **kwargs: `size`, `crop`, `augment`, `cache_dir`, `dtype`, `memory_cache_mb` of
            `DepthDataset`.

    Raises:
        FileNotFoundError: `root` or a folder is missing, or a photo has no f/8 photo or depth
            file (the message names the file).
        DataFormatError: an unreadable file, photos and depth of different sizes, or a
            camera with different values for several shots.
        ValueError: an unknown `focus`, or `relative`/`register` with `focus="synthesized"`.

    Example:
        >>> import tempfile, numpy as np, imageio.v3 as iio
        >>> root = Path(tempfile.mkdtemp())
        >>> for sub, name in [("dfd_dataset_indoor_N2_8/rgb", "2018-01-01T10:00:00.JPG"),
        ...                   ("dfd_dataset_indoor_N8/rgb", "2018-01-01T10:00:00.JPG"),
        ...                   ("dfd_dataset_indoor_N2_8/depth", "2018-01-01T10:00:00.3.png")]:
        ...     (root / sub / "train").mkdir(parents=True)
        ...     data = np.full((8, 8), 2000, np.uint16) if name.endswith("png") else \\
        ...         np.full((8, 8, 3), 128, np.uint8)
        ...     iio.imwrite(root / sub / "train" / name, data)
        >>> sample = DSLR(root)[0]
        >>> sample["focused"].shape, float(sample["depth"].mean())
        (torch.Size([1, 3, 8, 8]), 2.0)
        >>> rendered = DSLR(root, focus="synthesized")[0]
        >>> rendered["focused"].shape, rendered["camera"].focus_distance.tolist()
        (torch.Size([2, 3, 8, 8]), [2.0, 8.0])
        >>> one_plane = DSLR(root, focus="synthesized", focus_fractions=[0.2])[0]
        >>> one_plane["focused"].shape
        torch.Size([1, 3, 8, 8])
    """

    name = "dslr"

    def __init__(
        self,
        root: str | Path,
        split: str = "train",
        depth_scale: float = 1e-3,
        sensor_width_px: int = 7360,
        wide: str = "f2.8",
        reference: str = "f8",
        depth: str = "depth",
        preset: CameraPreset = DSLR_PRESET,
        camera: str | Path | CameraSettings | None = None,
        max_gap_s: float = 10.0,
        scenes: slice | range | list[int] | None = None,
        relative: bool = False,
        register: bool | None = None,
        focus: str = "real",
        focus_fractions: tuple[float, ...] | list[float] = PAPER_FOCUS_FRACTIONS,
        **kwargs: Any,
    ):
        super().__init__(preset, **kwargs)
        fractions = tuple(focus_fractions) if isinstance(focus_fractions, (list, tuple)) else ()
        require_args(*((name, value, value > 0, f"> 0 {unit}") for name, value, unit in (
            ("depth_scale", depth_scale, "metres per unit"), ("max_gap_s", max_gap_s, "seconds"),
            ("sensor_width_px", sensor_width_px, "pixels"))),
            ("focus", focus, focus in FOCUS_MODES, f"one of {', '.join(FOCUS_MODES)}"),
            ("focus_fractions", focus_fractions, bool(fractions) and all(
                isinstance(f, (int, float)) and 0 < f <= 1 for f in fractions),
             "a list of fractions of the depth cap in (0, 1], one per focused image"))
        if focus == "synthesized" and (relative or register):
            raise ValueError(f"DSLR: {'relative' if relative else 'register'}=True applies to "
                             "the real f/2.8 photos; focus='synthesized' renders the focused "
                             "images from the f/8 photo and the depth")
        #: `"real"` (the f/2.8 photo) or `"synthesized"` (rendered from the f/8 photo and depth)
        self.focus = focus
        #: where the synthesised focused images are focused: fractions of the depth cap
        self.focus_fractions = tuple(float(f) for f in fractions)
        self.root = require_root(root, "DSLR", LAYOUT)
        self.depth_scale = float(depth_scale)
        self.sensor_width_px = int(sensor_width_px)
        self.reference_f_number = 8.0
        self.floor_px = 0.0
        self.relative = bool(relative)
        self.register = self.relative if register is None else bool(register)
        self.exposure_gain: list[float] | None = None
        self.settings: CameraSettings | None = None
        # one focused photo per scene: per-shot values of another count are refused by name
        if isinstance(camera, CameraSettings):
            self.settings = settings_for_shots(camera, 1, "camera", ONE_SHOT)
        elif camera is not None:
            file = CameraFile.read(camera, 1, ONE_SHOT)
            self.settings, self.floor_px = file.settings, file.focus_floor_px
            if file.reference_f_number is not None:
                self.reference_f_number = file.reference_f_number
            self.exposure_gain = None if file.exposure_gain is None else list(file.exposure_gain)
        if (self.root / WIDE_FOLDER).is_dir():
            folders = [self.root / WIDE_FOLDER / "rgb" / split,
                       self.root / REFERENCE_FOLDER / "rgb" / split,
                       self.root / WIDE_FOLDER / "depth" / split]
        else:
            folders = [self.root / split / name for name in (wide, reference, depth)]
        missing = [str(folder) for folder in folders if not folder.is_dir()]
        photos = [] if missing else _files(folders[0], PHOTO_SUFFIXES)
        if not photos:
            why = f"missing folder {missing[0]!r}" if missing else f"no photos in {str(folders[0])!r}"
            raise FileNotFoundError(f"DSLR: {why}. Expected:\n{LAYOUT}")
        references = pair_files(photos, _files(folders[1], PHOTO_SUFFIXES), "f/8 photo",
                                max_gap_s)
        depths = pair_files(photos, _files(folders[2], (".png",)), "depth file", max_gap_s)
        self.files: list[tuple[Path, Path, Path]] = list(zip(photos, references, depths,
                                                             strict=True))
        if scenes is not None:
            kept = list(range(len(self.files)))[scenes] if isinstance(scenes, slice) \
                else list(scenes)
            require_args(("scenes", scenes, kept and all(0 <= i < len(self.files) for i in kept),
                          f"indices among the {len(self.files)} scenes of {str(folders[0])!r}"))
            self.files = [self.files[i] for i in kept]
        self.ids.extend(w.stem for w, _, _ in self.files)

    def reference_settings(self, camera: CameraSettings) -> CameraSettings:
        """The settings of the f/8 photo (`image`): `camera` at `reference_f_number`, e.g. for
        `estimate_depth(image_settings=...)`."""
        return camera.replace(f_number=torch.full_like(camera.f_number, self.reference_f_number))

    def lens_settings(self, width: int) -> CameraSettings:
        """The `(1,)` settings of the f/2.8 photos `width` pixels wide: the camera JSON's, else
        the preset's with the full sensor's pitch scaled to that width."""
        if self.settings is not None:
            return self.settings.to(self.dtype)
        camera = self.preset.settings(self.dtype)
        return camera.replace(pixel_pitch=camera.pixel_pitch * (self.sensor_width_px / width))

    def load(self, index: int) -> dict[str, Any]:
        wide_path, ref_path, depth_path = self.files[index]
        image = read_photo(ref_path, dtype=self.dtype)[0]
        depth = read_depth_png(depth_path, self.depth_scale, dtype=self.dtype)
        mask = valid_depth_mask(depth)
        if self.focus == "synthesized":  # the focused images are rendered by `DepthDataset`
            require_one_size((ref_path, image), (depth_path, depth))
            require_valid_depth(mask, repr(str(depth_path)))
            camera = paper_focus(self.lens_settings(image.shape[-1]), self.preset.depth_cap,
                                 self.focus_fractions)
            return {"image": image, "camera": camera, "depth": fill_unknown(depth, mask),
                    "mask": mask}
        focused = read_photo(wide_path, dtype=self.dtype)[0]
        require_one_size((wide_path, focused), (ref_path, image), (depth_path, depth))
        camera = self.lens_settings(image.shape[-1])
        pair = {"image": image, "focused": focused[None]}
        if self.register:
            pair = register_focused(pair)
            del pair["motion"]
        if self.relative:
            pair["image"], camera = relative_pair(pair["image"], camera, self.reference_f_number,
                                                  self.floor_px, self.exposure_gain)
        require_valid_depth(mask, repr(str(depth_path)))
        return {**pair, "camera": camera, "depth": fill_unknown(depth, mask), "mask": mask}
