"""A stated side of one focus plane (`estimate_depth(side=...)`, `defocus predict --side`)."""

import pytest
import torch
from PIL import Image
from skimage import data

from defocus.cli import main
from models.depth_from_photos import estimate_depth
from models.depth_from_photos.side import fold_to_side, off_side
from models.plotting import SIDE_KEY
from optics import CameraSettings, render_focal_stack

FOCUS = 2.0
RANGE = (0.5, 10.0)
#: 50 mm f/2 focused at 2 m, 0.1 mm pixels: 6.4 px of blur at infinity; a disk, as `defocus
#: predict` takes a real lens's PSF to be
CAMERA = CameraSettings(0.05, 2.0, [FOCUS], 1e-4, aperture="disk")
#: the scene: a third at 0.9 m (a blur of 7.8 px, more than anything beyond 2 m up to 10 m
#: gives: 5.1 px), a third at 3 m (2.1 px, as its mirror 1.5 m) and a third at 6 m (4.3 px)
BANDS = (0.9, 3.0, 6.0)


def _scene(dtype=torch.float32):
    grey = torch.from_numpy(data.camera()[100:196, 100:244].copy()).to(dtype) / 255
    image = (0.05 + 0.9 * torch.stack([grey, grey.flip(1), grey.flip(0)]))[None]
    depth = torch.cat([torch.full((1, 1, 96, 48), d, dtype=dtype) for d in BANDS], 3)
    focused = render_focal_stack(image, depth, CAMERA.to(dtype))[0]
    return image[0], focused, depth[0]


def _band_medians(depth):
    # each band's median, away from the band edges the windows straddle
    return [float(depth[0, 16:80, 48 * i + 12:48 * i + 36].median()) for i in range(3)]


@pytest.fixture(scope="module")
def scene():
    return _scene()


@pytest.mark.parametrize("side", ["beyond", "before"])
def test_stated_side_places_each_mirrored_blur_and_keeps_the_contradicting_ones(scene, side):
    """The 3 m band is blurred as its mirror at 1.5 m: the statement picks the side. The 0.9 m
    band is blurred more than any depth beyond the plane allows: under "beyond" it stays near
    and is counted off side. Under "before" the 3 m and 6 m bands go to their mirrors (1.5 m,
    1.2 m), as a user who states it wrongly gets."""
    image, focused, _ = scene
    out = estimate_depth(focused, CAMERA, RANGE, image=image, side=side, max_pixels=20000)
    assert out["side"] == side and out["focus_plane"] == FOCUS and out["mirrored_depths"] is None
    near, middle, far = _band_medians(out["depth"])
    assert near == pytest.approx(0.9, rel=0.05)
    if side == "beyond":  # the 6 m band's depth is the sweep's matter: here only its side
        assert middle == pytest.approx(3.0, rel=0.2) and far > 1.5 * FOCUS
    else:
        assert middle == pytest.approx(1 / (2 / FOCUS - 1 / 3.0), rel=0.2) and far < FOCUS
    off = out["off_side"][0]
    if side == "beyond":
        assert off[16:80, 12:36].float().mean() > 0.9 and not off[16:80, 60:].any()
    else:
        assert not off.any()  # every blur here has a depth before the plane within the range


def test_no_statement_warns_of_the_mirrored_depths(scene):
    image, focused, _ = scene
    with pytest.warns(UserWarning, match="mirror"):
        out = estimate_depth(focused, CAMERA, RANGE, image=image, max_pixels=20000)
    assert "side" not in out and out["mirrored_depths"] is not None


def test_fold_and_off_side_agree_with_the_thin_lens(dtype):
    """A folded depth has the blur of the depth it came from; off-side depths are exactly those
    whose mirror leaves the range."""
    depth = torch.linspace(0.5, 10.0, 500, dtype=dtype)
    blur = (1 / depth - 1 / FOCUS).abs()
    for side in ("beyond", "before"):
        off = off_side(depth, FOCUS, RANGE, side)
        folded = torch.where(off, depth, fold_to_side(depth, FOCUS, RANGE, side))
        inside = (folded > RANGE[0] + 1e-9) & (folded < RANGE[1] - 1e-9)
        torch.testing.assert_close((1 / folded - 1 / FOCUS).abs()[inside], blur[inside])
        on_side = folded >= FOCUS if side == "beyond" else folded <= FOCUS
        assert bool((on_side | off).all())
        mirror_inverse = 2 / FOCUS - 1 / depth
        leaves = (mirror_inverse < 1 / RANGE[1]) if side == "beyond" else \
            (mirror_inverse > 1 / RANGE[0])
        wrong_side = depth < FOCUS if side == "beyond" else depth > FOCUS
        assert torch.equal(off, wrong_side & leaves)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"side": "left"}, "side must be one of"),
    ({"side": "beyond", "settings": CameraSettings(0.05, 2.0, [2.0, 6.0], 1e-4)},
     "focused at 2, 6 m"),
])
def test_bad_side_is_refused_by_name(scene, kwargs, match):
    image, focused, _ = scene
    settings = kwargs.pop("settings", CAMERA)
    shots = focused if settings.n_shots == 1 else focused.expand(2, -1, -1, -1)
    with pytest.raises(ValueError, match=match):
        estimate_depth(shots, settings, RANGE, image=image, **kwargs)


def _write(path, photo):
    Image.fromarray((photo.clamp(0, 1).permute(1, 2, 0).numpy() * 255).round()
                    .astype("uint8")).save(path)
    return str(path)


def test_predict_side_in_the_summary_and_the_figure(scene, tmp_path, capsys):
    """`defocus predict --side beyond` names the side and the share of pixels that contradict
    it (the 0.9 m band: about a third), stores them in figure.png, and warns of no mirror."""
    image, focused, _ = scene
    aif, one = _write(tmp_path / "aif.png", image), _write(tmp_path / "f.png", focused[0])

    def predict(shots, distances, side, out):
        return main(["predict", "--image", aif, "--focused", *shots, "--linear",
                     "--focus-distance", *distances, "--f-number", "2", "--focal-length",
                     "0.05", "--pixel-pitch", "1e-4", "--depth-range", "0.5", "10", "--quiet",
                     "--side", side, "--out", str(tmp_path / out)])

    assert predict([one], ["2"], "beyond", "b") == 0
    out = capsys.readouterr().out
    assert "stated: the scene lies beyond the focus plane at 2 m" in out
    assert "may lie mirrored" not in out
    share = float(out.split("but ")[1].split("%")[0]) / 100
    assert 0.25 < share < 0.4  # the 0.9 m band, a third of the pixels
    with Image.open(tmp_path / "b" / "figure.png") as figure:
        stated, focus, stored = figure.text[SIDE_KEY].split()
    assert (stated, float(focus)) == ("beyond", 2.0)
    assert float(stored) == pytest.approx(share, abs=1e-3)
    other = _write(tmp_path / "g.png", focused[0].flip(-1))
    assert predict([one, other], ["2", "6"], "before", "c") == 2
    err = capsys.readouterr().err
    assert "side='before'" in err and "focused at 2, 6 m" in err and len(err.splitlines()) == 1


def test_side_option_in_the_help(capsys):
    with pytest.raises(SystemExit):
        main(["predict", "--help"])
    assert "--side {beyond,before,both}" in capsys.readouterr().out
