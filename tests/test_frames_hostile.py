"""`pcreg run` on folders of frames and videos a user brings as they are: phone photographs tagged with an EXIF
orientation, frames of mixed sizes, a video whose first frames do not decode. Each case ends in exit 0 with the
frames labelled on the grid of their key frame, or in one line naming the file, exit 2, the frames labelled before
it kept: never a frame labelled turned against its key frame without a word."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest
from PIL import Image

from pcreg.cli import main
from pcreg.export import read_labels
from _runs import one_line_errors


def _scene(shape, n, seed=0):
    """``n`` frames (H, W, 3) uint8 RGB of a textured scene drifting right by 1 px a frame, and the key labels."""
    h, w = shape
    rng = np.random.default_rng(seed)
    scene = cv2.GaussianBlur(rng.integers(0, 256, (h, w + n, 3), dtype=np.uint8), (0, 0), 1.5)
    frames = [np.ascontiguousarray(scene[:, n - i:n - i + w]) for i in range(n)]
    labels = (np.arange(h)[:, None] * np.ones((1, w)) > h / 2).astype(np.uint8)
    return frames, labels


def _jpeg(path, rgb, orientation=None):
    """``rgb`` saved as a JPEG, tagged with an EXIF ``orientation`` (None: no tag)."""
    exif = Image.Exif()
    if orientation is not None:
        exif[0x0112] = orientation
    Image.fromarray(rgb).save(path, quality=95, exif=exif.tobytes())


def _phone_folder(tmp_path, shape=(48, 48), n=4, turned=2):
    """A folder of JPEGs ``f0.jpg ...`` as a phone leaves them: frame ``turned`` stored a quarter turn off and tagged
    orientation 6, so that a viewer shows it as the others; the key labels beside it."""
    frames, labels = _scene(shape, n)
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, rgb in enumerate(frames):
        if i == turned:
            _jpeg(folder / f"f{i}.jpg", np.ascontiguousarray(np.rot90(rgb, 1)), 6)
        else:
            _jpeg(folder / f"f{i}.jpg", rgb)
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    return folder, tmp_path / "key.png"


@pytest.mark.parametrize("shape", [(48, 48), (48, 64)], ids=["square", "landscape"])
def test_a_frame_tagged_with_another_orientation_than_the_key_frame_is_refused_by_name(tmp_path, capsys, shape):
    folder, key = _phone_folder(tmp_path, shape)
    out = tmp_path / "out"
    args = ["run", str(folder), "--labels", str(key), "--out", str(out)]
    assert main(args) == 2  # a square frame was labelled turned against its key frame, exit 0
    err = one_line_errors(capsys)
    assert len(err) == 1 and "f2.jpg has EXIF orientation 6" in err[0] and "f0.jpg has no EXIF orientation" in err[0]
    assert "exiftran -ai" in err[0]
    assert json.loads((out / "run.json").read_text())["done"] == 2  # the frames before it kept
    # turned as shown, the same command goes on from it
    from PIL import ImageOps

    with Image.open(folder / "f2.jpg") as im:
        upright = ImageOps.exif_transpose(im)
    upright.save(folder / "f2.jpg", quality=95)
    assert main(args) == 0
    assert all(read_labels(out / f"f{i}.png").shape == shape for i in range(4))


def test_a_frame_of_another_size_is_refused_with_both_sizes(tmp_path, capsys):
    frames, labels = _scene((48, 64), 4)
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, rgb in enumerate(frames):
        cv2.imwrite(str(folder / f"f{i}.png"), cv2.resize(rgb, (80, 60)) if i == 2 else rgb)
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    assert main(["run", str(folder), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "out")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "f2.png: 80x60 px, the first frame f0.png 64x48" in err[0] and "resize" in err[0]


def test_several_key_frames_refuse_a_turned_frame_too(tmp_path, capsys):
    folder, _ = _phone_folder(tmp_path, (48, 48), n=5, turned=2)
    keys = tmp_path / "keys"
    keys.mkdir()
    _, labels = _scene((48, 48), 5)
    for k in (0, 4):
        cv2.imwrite(str(keys / f"f{k}.png"), labels)
    assert main(["run", str(folder), "--labels", str(keys), "--out", str(tmp_path / "out")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "f2.jpg has EXIF orientation 6" in err[0]


@pytest.mark.parametrize("orientation, square", [(3, False), (2, False), (6, True)])
def test_a_key_frame_whose_orientation_its_labels_size_cannot_tell_is_said(tmp_path, capsys, orientation, square):
    frames, labels = _scene((48, 48) if square else (48, 64), 4)
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, rgb in enumerate(frames):
        _jpeg(folder / f"f{i}.jpg", rgb, orientation)
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(tmp_path / "key.png"), "--out", str(out)]) == 0
    err = one_line_errors(capsys)
    said = [line for line in err if f"EXIF orientation {orientation}" in line]
    assert len(said) == 1 and said[0].startswith("pcreg: note: ") and "f0.jpg" in said[0] and "exiftran" in said[0]
    assert "orientation" in json.loads((out / "run.json").read_text())["notes"]


def test_a_quarter_turn_of_frames_not_square_says_its_masks_lie_on_the_pixels_as_stored(tmp_path, capsys):
    frames, labels = _scene((48, 64), 4)
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, rgb in enumerate(frames):
        _jpeg(folder / f"f{i}.jpg", rgb, 6)
    cv2.imwrite(str(tmp_path / "key.png"), labels)  # drawn on the pixels as stored: their size says so
    out = tmp_path / "out"
    assert main(["run", str(folder), "--labels", str(tmp_path / "key.png"), "--out", str(out)]) == 0
    said = [line for line in one_line_errors(capsys) if "EXIF orientation 6" in line]
    assert len(said) == 1 and "fit the pixels as stored" in said[0] and "CVAT" in said[0] and "exiftran" in said[0]
    assert "orientation" in json.loads((out / "run.json").read_text())["notes"]
    assert main(["export", str(out), "--format", "cvat-mask", "--to", str(tmp_path / "cvat.zip")]) == 0
    assert any("EXIF orientation 6" in line for line in one_line_errors(capsys))  # the export says it again


def test_the_command_as_a_process_refuses_a_turned_frame_in_one_line(tmp_path):
    folder, key = _phone_folder(tmp_path)
    p = subprocess.run([sys.executable, "-m", "pcreg.cli", "run", str(folder), "--labels", str(key), "--out",
                        str(tmp_path / "out")], capture_output=True, text=True, timeout=600)
    lines = [line for line in p.stderr.splitlines() if line.strip() and "%|" not in line]
    assert p.returncode == 2 and len(lines) == 1 and "f2.jpg has EXIF orientation 6" in lines[0], p.stderr


def _video_without_its_first_key_frame(tmp_path, suffix):
    """``(whole, cut, key.png)``: an H.264 video of 8 frames, a key frame every 4, and a copy of it whose first packet,
    the key frame, is left out (as a cut without re-encoding off a key frame leaves it)."""
    import av

    from _videos import mux_all

    frames, labels = _scene((48, 64), 8)
    whole, cut = tmp_path / f"whole{suffix}", tmp_path / f"cut{suffix}"
    with av.open(str(whole), "w") as c:
        s = c.add_stream("libx264", rate=10, options={"g": "4", "bf": "0"})
        s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
        mux_all(c, s, frames)
    with av.open(str(whole)) as src, av.open(str(cut), "w") as out:
        stream = out.add_stream_from_template(src.streams.video[0])
        packets = [p for p in src.demux(src.streams.video[0]) if p.dts is not None]
        assert packets[0].is_keyframe and not packets[1].is_keyframe
        for p in packets[1:]:
            p.stream = stream
            out.mux(p)
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    return whole, cut, tmp_path / "key.png"


@pytest.mark.parametrize("suffix", [".mkv", ".mp4"])
def test_a_video_that_begins_without_its_key_frame_is_labelled_from_its_first_frame_that_decodes(tmp_path, capsys, suffix):
    whole, cut, key = _video_without_its_first_key_frame(tmp_path, suffix)
    assert main(["run", str(whole), "--labels", str(key), "--out", str(tmp_path / "whole_out")]) == 0
    assert "do not decode" not in capsys.readouterr().err
    out = tmp_path / "out"
    # before: the MP4 was refused as truncated ("ends after 4 of the 7 frames"), the Matroska file run without a word
    assert main(["run", str(cut), "--labels", str(key), "--out", str(out)]) == 0
    said = [line for line in one_line_errors(capsys) if "do not decode" in line]
    assert len(said) == 1 and said[0].startswith(f"pcreg: note: {cut}: its first 3 frame(s) do not decode")
    assert "at 0.4 s" in said[0]
    assert "do not decode" in json.loads((out / "run.json").read_text())["notes"]["start"]
    assert sorted(p.name for p in out.glob("0*.png")) == [f"{i:06d}.png" for i in range(4)]


def _two_streams(path, sizes, frames):
    """A Matroska file of two H.264 video streams of ``sizes`` ((W, H) each), both of ``frames`` resized."""
    import av

    with av.open(str(path), "w") as c:
        streams = []
        for w, h in sizes:
            s = c.add_stream("libx264", rate=10)
            s.width, s.height, s.pix_fmt = w, h, "yuv420p"
            streams.append(s)
        for rgb in frames:
            for s in streams:
                image = av.VideoFrame.from_ndarray(np.ascontiguousarray(cv2.resize(rgb, (s.width, s.height))), format="rgb24")
                for packet in s.encode(image):
                    c.mux(packet)
        for s in streams:
            for packet in s.encode():
                c.mux(packet)


def test_a_video_of_two_streams_says_which_it_reads(tmp_path, capsys):
    frames, labels = _scene((48, 64), 4)
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    small_first = tmp_path / "small_first.mkv"
    _two_streams(small_first, [(32, 24), (64, 48)], frames)
    # before: "labels are 64x48, the key frame 000000 is 32x24", not a word of the other stream
    assert main(["run", str(small_first), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "a")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "holds 2 video streams: pcreg reads the first (#0, 32x24), not #1 64x48" in err[0]
    assert "-map 0:v:1" in err[0]
    same = tmp_path / "same.mkv"
    _two_streams(same, [(64, 48), (64, 48)], frames)
    assert main(["run", str(same), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "b")]) == 0
    said = [line for line in one_line_errors(capsys) if "video streams" in line]
    assert len(said) == 1 and said[0].startswith(f"pcreg: note: {same} holds 2 video streams")


def _boxes(data: bytes) -> list[tuple[bytes, int, int]]:
    """An MP4's top-level boxes: (kind, start, size)."""
    import struct

    found, at = [], 0
    while at < len(data):
        size, kind = struct.unpack(">I4s", data[at:at + 8])
        found.append((kind, at, size))
        at += size
    return found


@pytest.mark.parametrize("how", ["moov dropped", "mdat to the end", "QuickTime without ftyp"])
def test_an_mp4_whose_recording_stopped_before_its_index_is_named_so(tmp_path, capsys, how):
    """A recording stopped before its end (power lost) holds its frames but not the index written last: it was
    refused as "not a video FFmpeg can read ... not a video, or truncated or damaged", with no word of what is
    missing or how to get the frames back. An old QuickTime file has no ``ftyp``: it may start with ``wide``."""
    whole, _, key = _video_without_its_first_key_frame(tmp_path, ".mp4")
    data = whole.read_bytes()
    boxes = {kind: (at, size) for kind, at, size in _boxes(data)}
    assert b"moov" in boxes and b"mdat" in boxes
    at, size = boxes[b"moov"]
    cut = tmp_path / ("unfinished.mov" if how.startswith("QuickTime") else "unfinished.mp4")
    if how == "moov dropped":
        cut.write_bytes(data[:at] + data[at + size:])
    elif how.startswith("QuickTime"):  # ftyp's place taken by an 8-byte wide box, the index dropped
        ftyp, ftyp_size = boxes[b"ftyp"]
        assert ftyp == 0 and at > ftyp_size
        cut.write_bytes(b"\0\0\0\x08wide" + data[ftyp_size:at] + data[at + size:])
    else:  # as a recorder leaves it: the frames' box's size not yet written (0: to the end), no index after it
        mdat, _ = boxes[b"mdat"]
        body = data[:at] if at > mdat else data[:at] + data[at + size:]
        cut.write_bytes(body[:mdat] + b"\0\0\0\0" + body[mdat + 4:])
    out = tmp_path / "out"
    assert main(["run", str(cut), "--labels", str(key), "--out", str(out)]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and err[0].startswith(f"pcreg: error: {cut}: an MP4 or QuickTime file without its index (no moov box)"), err
    assert "untrunc" in err[0]
    # any other file FFmpeg cannot read keeps the general words
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"\0\0\0\x18ftypisom" + bytes(range(256)) * 4)
    assert main(["run", str(junk), "--labels", str(key), "--out", str(tmp_path / "junk_out")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "not a video FFmpeg can read" in err[0] and "moov" not in err[0], err
