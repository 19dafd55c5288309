"""`datasets.photos.read_photo` on the sample formats scientific cameras, ImageJ and raw
developers write: every bit kept and compared with the values written, or a refusal that names
the file, what it holds and what is read."""

from __future__ import annotations

import warnings

import numpy as np
import png
import pytest
import tifffile
import torch
from kornia.color import rgb_to_linear_rgb

from datasets.io import DataFormatError
from datasets.photos import read_photo

SHAPE = (12, 18)


def _stored(dtype=np.uint16, shape=SHAPE, high=None, seed=0) -> np.ndarray:
    """Samples over the whole range of `dtype` (or [0, high]), both ends included."""
    high = np.iinfo(dtype).max if high is None else high
    values = np.random.default_rng(seed).integers(0, high, shape, dtype=np.uint64, endpoint=True)
    values.flat[:2] = (0, high)
    return values.astype(dtype)


def _read(path, encoding="linear") -> np.ndarray:
    image, _ = read_photo(path, dtype=torch.float64, encoding=encoding)
    assert image.shape == (3, *image.shape[1:])
    return image.numpy()


def _grey(stored: np.ndarray) -> np.ndarray:
    """What a grey photo reads as: its samples over the type's maximum, in R, G and B."""
    return np.broadcast_to(stored / np.iinfo(stored.dtype).max, (3, *stored.shape))


@pytest.mark.parametrize("byteorder", ["<", ">"])
def test_a_16_bit_grey_tiff_keeps_all_16_bits_in_either_byte_order(tmp_path, byteorder):
    """ImageJ writes big-endian: Pillow opens it as I;16B, which its RGB conversion clipped."""
    stored = _stored()
    path = tmp_path / "grey.tif"
    tifffile.imwrite(path, stored.astype(f"{byteorder}u2"), byteorder=byteorder)
    np.testing.assert_allclose(_read(path), _grey(stored), rtol=0, atol=1e-12)
    srgb = rgb_to_linear_rgb(torch.from_numpy(_grey(stored).copy())).numpy()
    np.testing.assert_allclose(_read(path, "srgb"), srgb, rtol=0, atol=1e-12)


def test_10_bit_samples_in_big_endian_16_bit_words_are_not_clipped(tmp_path):
    stored = _stored(high=1023)
    tifffile.imwrite(tmp_path / "ten.tif", stored.astype(">u2"), byteorder=">")
    read = _read(tmp_path / "ten.tif")
    np.testing.assert_allclose(read, _grey(stored), rtol=0, atol=1e-12)
    assert read.max() == pytest.approx(1023 / 65535)


@pytest.mark.parametrize("planarconfig", ["contig", "separate"])
def test_a_big_endian_16_bit_rgb_tiff_keeps_all_16_bits(tmp_path, planarconfig):
    stored = _stored(shape=(*SHAPE, 3))
    path = tmp_path / "rgb.tif"
    tifffile.imwrite(path, (stored if planarconfig == "contig" else np.moveaxis(stored, -1, 0))
                     .astype(">u2"), byteorder=">", photometric="rgb", planarconfig=planarconfig)
    np.testing.assert_allclose(_read(path), np.moveaxis(stored / 65535, -1, 0), rtol=0,
                               atol=1e-12)


def test_a_32_bit_unsigned_grey_tiff_is_divided_by_its_types_maximum(tmp_path):
    stored = _stored(np.uint32)
    tifffile.imwrite(tmp_path / "u32.tif", stored)
    np.testing.assert_allclose(_read(tmp_path / "u32.tif"), _grey(stored), rtol=0, atol=1e-12)


@pytest.mark.parametrize("dtype", ["<i2", ">i2", "<i4"])
def test_a_signed_integer_tiff_is_refused_naming_what_it_holds(tmp_path, dtype):
    stored = _stored(np.uint16).astype(np.int32) - 32768
    path = tmp_path / "signed.tif"
    tifffile.imwrite(path, stored.astype(dtype), byteorder=dtype[0])
    name = np.dtype(dtype).name
    with pytest.raises(DataFormatError,
                       match=rf"signed\.tif.*holds {name} samples: signed.*unsigned integer"):
        read_photo(path)


def test_a_16_bit_grey_alpha_png_is_read_as_grey_as_an_8_bit_one_is(tmp_path):
    """Pillow opens a 16-bit grey+alpha PNG as RGBA: pypng reads it, grey in R, G and B."""
    stored = _stored(shape=(*SHAPE, 2))
    for bits, samples in ((16, stored), (8, (stored >> 8).astype(np.uint8))):
        path = tmp_path / f"la{bits}.png"
        with open(path, "wb") as handle:
            png.Writer(SHAPE[1], SHAPE[0], greyscale=True, alpha=True, bitdepth=bits).write(
                handle, samples.reshape(SHAPE[0], -1))
        np.testing.assert_allclose(_read(path), _grey(samples[..., 0]), rtol=0, atol=1e-12)


def test_a_16_bit_grey_alpha_tiff_drops_the_alpha(tmp_path):
    stored = _stored(shape=(*SHAPE, 2))
    tifffile.imwrite(tmp_path / "la.tif", stored.astype(">u2"), byteorder=">",
                     photometric="minisblack", extrasamples=["unassalpha"])
    np.testing.assert_allclose(_read(tmp_path / "la.tif"), _grey(stored[..., 0]), rtol=0,
                               atol=1e-12)


#: EXIF orientation -> the stored `(H,W)` array turned upright.
UPRIGHT = {1: lambda a: a, 2: lambda a: a[:, ::-1], 3: lambda a: a[::-1, ::-1],
           4: lambda a: a[::-1], 5: lambda a: a.T, 6: lambda a: np.rot90(a, -1),
           7: lambda a: a.T[::-1, ::-1], 8: lambda a: np.rot90(a, 1)}


@pytest.mark.parametrize("orientation", range(1, 9))
@pytest.mark.parametrize("dtype", ["u1", "<u2", ">u2"])
def test_a_grey_tiff_is_turned_upright(tmp_path, orientation, dtype):
    """Pillow 13 scrambled 8-bit grey TIFFs turned by 5-8 when it opened them by name."""
    stored = _stored(np.dtype(dtype).newbyteorder("="))
    path = tmp_path / "grey.tif"
    tifffile.imwrite(path, stored.astype(dtype), byteorder=dtype[0] if len(dtype) > 2 else None,
                     extratags=[(274, "H", 1, orientation, True)])
    np.testing.assert_allclose(_read(path), _grey(UPRIGHT[orientation](stored)), rtol=0,
                               atol=1e-12)


@pytest.mark.parametrize("photometric, samples", [("miniswhite", SHAPE),
                                                  ("separated", (*SHAPE, 4))])
def test_a_tiff_neither_grey_nor_rgb_is_refused(tmp_path, photometric, samples):
    path = tmp_path / "odd.tif"
    tifffile.imwrite(path, _stored(shape=samples), photometric=photometric)
    with pytest.raises(DataFormatError, match=rf"odd\.tif.*holds {photometric.upper()} "
                                              r"samples.*grey \(min-is-black\) or RGB"):
        read_photo(path)


def _no_codec(*args, **kwargs):
    raise KeyError("<COMPRESSION.LZW: 5> requires the 'imagecodecs' package")


def test_pillow_reads_a_big_endian_grey_tiff_tifffile_cannot_decode_with_all_16_bits(
        tmp_path, monkeypatch):
    stored = _stored()
    tifffile.imwrite(tmp_path / "be.tif", stored.astype(">u2"), byteorder=">")
    monkeypatch.setattr(tifffile, "imread", _no_codec)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "8 bits only" warning: none are lost
        np.testing.assert_allclose(_read(tmp_path / "be.tif"), _grey(stored), rtol=0,
                                   atol=1e-12)


def test_a_32_bit_tiff_tifffile_cannot_decode_is_refused_not_clipped(tmp_path, monkeypatch):
    tifffile.imwrite(tmp_path / "u32.tif", _stored(np.uint32))
    monkeypatch.setattr(tifffile, "imread", _no_codec)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DataFormatError,
                           match=r"u32\.tif.*imagecodecs.*mode 'I'.*unsigned integer"):
            read_photo(tmp_path / "u32.tif")


def test_read_metadata_refuses_a_photo_whose_header_is_damaged(tmp_path):
    from PIL import Image

    from datasets.photos.metadata import read_metadata

    good = tmp_path / "good.jpg"
    Image.new("RGB", (8, 6)).save(good)
    damaged = tmp_path / "damaged.jpg"
    damaged.write_bytes(good.read_bytes()[:3] + b"\x00" * 40)  # a JPEG marker, then nothing
    with pytest.raises(ValueError, match=r"damaged\.jpg is not a photo that can be read"):
        read_metadata(damaged)  # used to return empty metadata without a word
    assert read_metadata(damaged, image_size=(6, 8)).orientation == 1  # a size given: the tags
    assert read_metadata(good).compressed
