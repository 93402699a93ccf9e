"""``pcreg.load_image`` in a script says what ``pcreg register`` notes of a file: transparent pixels it keeps as pixels
(``pcreg.load_image_and_mask`` leaves them out, as the command does), an EXIF orientation, damaged JPEG data."""

from __future__ import annotations

import warnings

import cv2
import numpy as np
import pytest

import pcreg
from pcreg import transforms as tf
from pcreg.errors import ImageWarning
from test_cli_hostile import _jpeg_turned


def _half_hidden(tmp_path):
    """A frame, and a PNG of it moved by (40, -15) px whose left 60% is the unmoved frame made transparent: what a
    viewer shows is the moved frame's right part alone. (reference path, moving path, T_ref_mov)"""
    base = pcreg.synthetic("syn2a", n_frames=1)[0].image
    h, w = base.shape[:2]
    T = tf.rigid2d(0.0, 40.0, -15.0)
    moved, _ = pcreg.warp(base, np.linalg.inv(T))
    rgba = np.dstack([moved, np.full((h, w), 255, np.uint8)])
    cut = int(0.6 * w)
    rgba[:, :cut, :3], rgba[:, :cut, 3] = base[:, :cut], 0
    ref, mov = tmp_path / "ref.png", tmp_path / "moving.png"
    cv2.imwrite(str(ref), base[:, :, ::-1])
    cv2.imwrite(str(mov), cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA))
    return ref, mov, T


def test_transparent_pixels_are_warned_of_and_load_image_and_mask_leaves_them_out(tmp_path):
    ref_path, mov_path, T = _half_hidden(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an opaque image: nothing to say
        ref = pcreg.load_image(ref_path)
    with pytest.warns(ImageWarning, match=r"moving\.png: 60% of its pixels are transparent \(alpha 0\), kept here as pixels") as said:
        mov = pcreg.load_image(mov_path)
    assert len(said) == 1 and "pcreg.load_image_and_mask(path)" in str(said[0].message)
    assert said[0].filename == __file__  # pointed at the caller's line, not pcreg's
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        (ref2, ref_mask), (mov2, mov_mask) = pcreg.load_image_and_mask(ref_path), pcreg.load_image_and_mask(mov_path)
    assert np.array_equal(ref2, ref) and np.array_equal(mov2, mov) and isinstance(ref_mask, str)
    assert not mov_mask[:, : int(0.6 * mov.shape[1])].any()
    masked = pcreg.register(ref2, mov2, reference_mask=ref_mask, moving_mask=mov_mask)
    assert tf.max_corner_error(masked.T_ref_mov, T, ref.shape) < 0.5


def test_an_exif_orientation_and_damaged_data_are_warned_of(tmp_path):
    img = pcreg.synthetic("syn2a", n_frames=1)[0].image[:, :, ::-1]
    turned = tmp_path / "phone shot.jpg"
    turned.write_bytes(_jpeg_turned(img))
    with pytest.warns(ImageWarning, match="EXIF orientation 6 has viewers show it turned by a quarter; pcreg reads the pixels as stored"):
        assert pcreg.load_image(turned).shape == img.shape
    with pytest.warns(ImageWarning, match="EXIF orientation 6"):
        pcreg.load_image_and_mask(turned)
    intact = cv2.imencode(".jpg", img)[1].tobytes()
    damaged = bytearray(intact)
    damaged[len(damaged) // 2: len(damaged) // 2 + 64] = bytes(range(64))
    bad, good = tmp_path / "bad.jpg", tmp_path / "good.jpg"
    bad.write_bytes(bytes(damaged))
    good.write_bytes(intact)
    with pytest.warns(ImageWarning, match=r"bad\.jpg: its decoder reports damaged data \(Corrupt JPEG data"):
        pcreg.load_image(bad)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pcreg.load_image(good)


def test_a_warning_of_a_file_read_inside_pcreg_points_at_the_callers_line(tmp_path):
    """``pcreg.crosscheck(path, path)`` reads its images inside pcreg: the warning named pcreg's own line."""
    img = pcreg.synthetic("syn2a", n_frames=1)[0].image[:, :, ::-1]
    turned, plain = tmp_path / "turned.jpg", tmp_path / "plain.jpg"
    turned.write_bytes(_jpeg_turned(img))
    cv2.imwrite(str(plain), img)
    with pytest.warns(ImageWarning, match="EXIF orientation 6") as said:
        pcreg.crosscheck(plain, turned)
    assert [w.filename for w in said if issubclass(w.category, ImageWarning)] == [__file__]
