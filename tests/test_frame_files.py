"""Frame files whose pixels say more than three colours: frames with an alpha channel (PNG, and videos whose pixel
format has one), read with their colours as stored and, where a pixel is transparent, said once a run."""

import cv2
import numpy as np
import pytest

from pcreg.cli import main

H, W = 48, 64


def _scene(i: int) -> np.ndarray:
    """(H, W, 3) uint8 BGR: a smooth texture moved ``i`` px right, and a bright right half (the object)."""
    rng = np.random.default_rng(0)
    texture = cv2.GaussianBlur(rng.integers(0, 255, (H, W + 8, 3), dtype=np.uint8), (0, 0), 2)
    img = np.roll(texture, i, axis=1)[:, :W].copy()
    img[:, W // 2:] //= 3
    img[:, W // 2:] += 160
    return img


def _key(path):
    cv2.imwrite(str(path), (np.arange(W)[None, :] >= W // 2).astype(np.uint8).repeat(H, axis=0))
    return path


def _folder(root, n=4, *, alpha=None, transparent=()):
    """``n`` PNG frames in ``root``: BGR, or BGRA with ``alpha`` everywhere and 0 in the top rows of frames
    ``transparent``."""
    root.mkdir()
    for i in range(n):
        img = _scene(i)
        if alpha is not None:
            img = np.dstack([img, np.full((H, W), alpha, np.uint8)])
            if i in transparent:
                img[:10, :, 3] = 0
        cv2.imwrite(str(root / f"f{i:02d}.png"), img)
    return root


def _labels(out):
    return {p.name: cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted(out.glob("*.png"))}


def test_opaque_rgba_frames_read_as_rgb_frames_without_a_note(tmp_path, capsys):
    key = _key(tmp_path / "key.png")
    for name, alpha in (("rgb", None), ("rgba", 255)):
        assert main(["run", str(_folder(tmp_path / name, alpha=alpha)), "--labels", str(key),
                     "--out", str(tmp_path / f"out-{name}")]) == 0
        assert "transparent" not in capsys.readouterr().err
    rgb, rgba = _labels(tmp_path / "out-rgb"), _labels(tmp_path / "out-rgba")
    assert list(rgb) == list(rgba) == ["f00.png", "f01.png", "f02.png", "f03.png"]
    for name in rgb:
        np.testing.assert_array_equal(rgb[name], rgba[name], err_msg=name)


def test_frames_with_transparent_pixels_are_said_once_naming_the_first(tmp_path, capsys):
    frames = _folder(tmp_path / "frames", alpha=255, transparent=(2, 3))
    assert main(["run", str(frames), "--labels", str(_key(tmp_path / "key.png")), "--out", str(tmp_path / "out")]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if "transparent pixels" in ln]
    assert len(notes) == 1, notes
    assert notes[0].startswith("pcreg: note: ") and f"{frames / 'f02.png'} has transparent pixels (640 of its 3072" in notes[0]


def test_a_video_with_transparent_pixels_is_said_once(tmp_path, capsys):
    av = pytest.importorskip("av")
    video = tmp_path / "clip.mov"
    with av.open(str(video), "w") as c:  # QuickTime Animation with alpha, as a compositing tool exports it
        s = c.add_stream("qtrle", rate=10)
        s.width, s.height, s.pix_fmt = W, H, "argb"
        for i in range(4):
            rgba = np.dstack([_scene(i)[:, :, ::-1], np.full((H, W), 255, np.uint8)])
            rgba[:10, :, 3] = 0 if i >= 2 else 255
            for packet in s.encode(av.VideoFrame.from_ndarray(rgba, format="rgba").reformat(format="argb")):
                c.mux(packet)
        for packet in s.encode():
            c.mux(packet)
    assert main(["run", str(video), "--labels", str(_key(tmp_path / "key.png")), "--out", str(tmp_path / "out")]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if "transparent pixels" in ln]
    assert len(notes) == 1 and f"{video} frame 000002 has transparent pixels" in notes[0], notes


def _tiff_with_thumbnail(path, image, thumbnail):
    """A TIFF whose second IFD is a reduced-resolution copy (NewSubfileType 1), as a scanner or camera writes one."""
    from PIL import Image, TiffImagePlugin

    with TiffImagePlugin.AppendingTiffWriter(str(path)) as tf:
        Image.fromarray(image).save(tf, format="TIFF")
        tf.newFrame()
        info = TiffImagePlugin.ImageFileDirectory_v2()
        info[254] = 1
        Image.fromarray(thumbnail).save(tf, format="TIFF", tiffinfo=info)
        tf.newFrame()


def test_a_multi_page_tiff_frame_or_key_is_refused_naming_its_pages(tmp_path, capsys):
    frames = _folder(tmp_path / "frames")
    key = _key(tmp_path / "key.png")
    cv2.imwritemulti(str(frames / "f02.tif"), [_scene(2), _scene(9), _scene(11)])
    (frames / "f02.png").unlink()
    assert main(["run", str(frames), "--labels", str(key), "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"pcreg: error: {frames / 'f02.tif'}: a TIFF of 3 pages") and "\n" not in err, err
    (frames / "f02.tif").unlink()
    labels = cv2.imread(str(key), cv2.IMREAD_UNCHANGED)
    cv2.imwritemulti(str(tmp_path / "key.tif"), [labels, 1 - labels])
    assert main(["run", str(frames), "--labels", str(tmp_path / "key.tif"), "--out", str(tmp_path / "b")]) == 2
    assert f"{tmp_path / 'key.tif'}: a TIFF of 2 pages" in capsys.readouterr().err


def test_a_one_page_tiff_and_one_with_a_thumbnail_read_as_their_image(tmp_path):
    from pcreg.registration.clouds import load_image

    cv2.imwrite(str(tmp_path / "one.tif"), _scene(0))
    _tiff_with_thumbnail(tmp_path / "thumb.tif", _scene(0)[:, :, ::-1], _scene(5)[::4, ::4, ::-1].copy())
    for name in ("one.tif", "thumb.tif"):
        np.testing.assert_array_equal(load_image(tmp_path / name), _scene(0)[:, :, ::-1], err_msg=name)


def test_a_transparent_frame_between_two_key_frames_is_said_once(tmp_path, capsys):
    frames = _folder(tmp_path / "frames", n=6, alpha=255, transparent=(2, 3))
    keys = tmp_path / "keys"
    keys.mkdir()
    for i in (0, 5):
        _key(keys / f"f{i:02d}.png")
    assert main(["run", str(frames), "--labels", str(keys), "--out", str(tmp_path / "out")]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if "transparent pixels" in ln]
    assert len(notes) == 1 and f"{frames / 'f02.png'} has transparent pixels" in notes[0], notes
