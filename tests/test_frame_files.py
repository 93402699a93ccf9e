"""Frame files whose pixels say more than three colours: frames with an alpha channel (PNG, and videos whose pixel
format has one), read with their colours as stored and, where a pixel is transparent, said once a run, kept in
run.json and said again by what reads the run."""

import json

import av
import cv2
import numpy as np
import pytest

from pcreg.cli import main
from _runs import kill_before_commit, one_line_errors

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


def test_a_jpeg_frame_decoded_around_damaged_data_is_said_once(tmp_path, capsys):
    """A folder of JPEG frames, two cut short (their end marker put back): labelled from the decoder's guesses
    without a word, where ``pcreg register`` of the same image says so. The first is named, kept in run.json."""
    import json

    frames = _folder(tmp_path / "frames")
    for png in sorted(frames.glob("*.png")):
        cv2.imwrite(str(png.with_suffix(".jpg")), cv2.imread(str(png)))
        png.unlink()
    for name in ("f02.jpg", "f03.jpg"):
        data = (frames / name).read_bytes()
        (frames / name).write_bytes(data[:len(data) * 2 // 3] + b"\xff\xd9")
    assert main(["run", str(frames), "--labels", str(_key(tmp_path / "key.png")), "--out", str(tmp_path / "out")]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if "damaged data" in ln]
    assert len(notes) == 1, notes
    assert notes[0].startswith(f"pcreg: note: {frames / 'f02.jpg'}: its decoder reports damaged data (Corrupt JPEG data")
    assert json.loads((tmp_path / "out" / "run.json").read_text())["notes"]["damaged"] == notes[0].removeprefix("pcreg: note: ")


def test_two_frames_of_one_name_are_named(tmp_path, capsys):
    """``f01.png`` beside ``f01.jpg``: the refusal named the folder ("two frames share a name (1 duplicates)"), not
    which files."""
    frames = _folder(tmp_path / "frames")
    cv2.imwrite(str(frames / "f01.jpg"), cv2.imread(str(frames / "f01.png")))
    assert main(["run", str(frames), "--labels", str(_key(tmp_path / "key.png")), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err == f"pcreg: error: {frames / 'f01.jpg'}: another frame of this name beside it, f01.png; keep one\n"


def test_a_video_with_transparent_pixels_is_said_once(tmp_path, capsys):
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


@pytest.mark.parametrize("bits", [12, 16])
def test_a_16_bit_video_of_a_12_bit_camera_is_said_to_read_nearly_black(tmp_path, capsys, bits):
    """A 12-bit grey camera's frames stored in 16 bits (gray16le FFV1, as a machine-vision recorder writes them) read
    at 0..16 of 255 with no word, where the same frames as 16-bit PNGs in a folder were noted. Noted once, and kept in
    run.json; frames that use the 16 bits are not."""
    video = tmp_path / "clip.mkv"
    with av.open(str(video), "w") as c:
        s = c.add_stream("ffv1", rate=10)
        s.width, s.height, s.pix_fmt = W, H, "gray16le"
        for i in range(4):
            grey = cv2.cvtColor(_scene(i), cv2.COLOR_BGR2GRAY).astype(np.uint16) * (16 if bits == 12 else 257)
            for packet in s.encode(av.VideoFrame.from_ndarray(grey, format="gray16le")):
                c.mux(packet)
        for packet in s.encode():
            c.mux(packet)
    out = tmp_path / "out"
    assert main(["run", str(video), "--labels", str(_key(tmp_path / "key.png")), "--out", str(out)]) == 0
    notes = [ln for ln in capsys.readouterr().err.splitlines() if "16-bit values" in ln]
    kept = json.loads((out / "run.json").read_text()).get("notes", {})
    if bits == 16:
        assert not notes and "dark" not in kept
        return
    assert len(notes) == 1 and f"{video} frame 000000: its 16-bit values lie in" in notes[0], notes
    assert "nearly black" in kept["dark"]


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


def _kept(out) -> dict | None:
    return json.loads((out / "run.json").read_text()).get("notes")


def _said(capsys, what="transparent pixels") -> list[str]:
    return [ln for ln in capsys.readouterr().err.splitlines() if what in ln]


@pytest.mark.parametrize("stop", [2, 3])
def test_a_transparent_frame_is_kept_in_run_json_with_its_frame_and_said_again_by_view_and_export(tmp_path, capsys,
                                                                                                  monkeypatch, stop):
    """The note is committed with the frame that met it (a run stopped before frame 2's commit has none; one stopped
    after it keeps it, and the resume does not replace it with frame 3's), and what reads the run says it."""
    from pcreg.recording.review import ReviewServer
    from pcreg.review import read_review

    frames = _folder(tmp_path / "frames", alpha=255, transparent=(2, 3))
    args = ["run", str(frames), "--labels", str(_key(tmp_path / "key.png"))]
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    assert main([*args, "--out", str(whole)]) == 0
    line = _said(capsys)[0].removeprefix("pcreg: note: ")
    assert f"{frames / 'f02.png'} has transparent pixels" in line and _kept(whole) == {"transparent": line}
    kill_before_commit(monkeypatch, stop)
    assert main([*args, "--out", str(cut)]) == 130
    monkeypatch.undo()
    assert _kept(cut) == (None if stop == 2 else {"transparent": line})
    assert main([*args, "--out", str(cut)]) == 0
    assert (cut / "run.json").read_bytes() == (whole / "run.json").read_bytes()
    capsys.readouterr()
    assert main(["view", str(whole), "--overlay", str(tmp_path / "overlay.mp4")]) == 0
    assert _said(capsys) == [f"pcreg: note: {line}"]
    with av.open(str(tmp_path / "overlay.mp4")) as c:  # and in the overlay video's comment
        assert c.metadata.get("comment") == line
    assert main(["export", str(whole), "--to", str(tmp_path / "cvat.zip")]) == 0
    assert _said(capsys) == [f"pcreg: note: {line}"]
    with ReviewServer(read_review(whole), web_port=0) as server:
        assert json.loads(server.review_json())["notes"] == [line]


def test_a_transparent_frame_between_two_key_frames_is_said_once_and_kept_in_run_json(tmp_path, capsys):
    frames = _folder(tmp_path / "frames", n=6, alpha=255, transparent=(2, 3))
    keys = tmp_path / "keys"
    keys.mkdir()
    for i in (0, 5):
        _key(keys / f"f{i:02d}.png")
    assert main(["run", str(frames), "--labels", str(keys), "--out", str(tmp_path / "out")]) == 0
    said = _said(capsys)  # once, naming the first such frame
    assert len(said) == 1 and f"{frames / 'f02.png'} has transparent pixels" in said[0], said
    line = said[0].removeprefix("pcreg: note: ")
    assert _kept(tmp_path / "out") == {"transparent": line}
    assert main(["export", str(tmp_path / "out"), "--to", str(tmp_path / "cvat.zip")]) == 0
    assert _said(capsys) == [f"pcreg: note: {line}"]


def test_a_run_json_without_notes_reads_as_before_and_a_malformed_one_is_refused(tmp_path, capsys):
    from pcreg.export import read_run
    from pcreg.runs.state import state_problem

    frames = _folder(tmp_path / "frames", alpha=255, transparent=(2,))
    out = tmp_path / "out"
    run = ["run", str(frames), "--labels", str(_key(tmp_path / "key.png")), "--out", str(out)]
    assert main(run) == 0
    state = json.loads((out / "run.json").read_text())
    line = state.pop("notes")["transparent"]
    (out / "run.json").write_text(json.dumps(state))  # as a run from before the notes were kept
    assert read_run(out).notes == ()
    capsys.readouterr()
    assert main(["export", str(out), "--to", str(tmp_path / "cvat.zip")]) == 0
    assert main(run) == 0  # all done: the resume reads no frame, and keeps the run.json as it was
    assert _said(capsys) == [] and "notes" not in json.loads((out / "run.json").read_text())
    for notes, problem in ((None, None), ({"transparent": line}, None), ({"interlaced": "x", "other": "y"}, None),
                           ({}, "notes"), ([line], "notes"), (line, "notes"), ({"transparent": 3}, "notes"),
                           ({"transparent": ""}, "notes"), ({"": line}, "notes"), ({"transparent": [line]}, "notes")):
        assert state_problem(state if notes is None else {**state, "notes": notes}) == problem, notes
    (out / "run.json").write_text(json.dumps({**state, "notes": [line]}))
    for command in (run, ["export", str(out), "--to", str(tmp_path / "x.zip"), "--force"],
                    ["view", str(out), "--overlay", str(tmp_path / "o.mp4")]):
        assert main(command) == 2
        err = one_line_errors(capsys)
        assert len(err) == 1 and f"{out / 'run.json'}" in err[0], (command, err)


def test_the_review_page_shows_the_notes_kept_in_run_json(tmp_path, capsys):
    from _browser import review_page_values

    frames = _folder(tmp_path / "frames", alpha=255, transparent=(2,))
    out = tmp_path / "out"
    assert main(["run", str(frames), "--labels", str(_key(tmp_path / "key.png")), "--out", str(out)]) == 0
    line = _kept(out)["transparent"]
    [shown] = review_page_values(str(out), "(() => { const d = document.getElementById('notes'); return d.hidden ? "
                                 "null : [...d.children].map((p) => [p.textContent, p.getBoundingClientRect().height > 0]); })()")
    assert shown == [[line, True]]


def _chunks(data: bytes) -> dict[bytes, int]:
    """Where each kind of a PNG's chunks first starts."""
    import struct

    at, found = 8, {}
    while at < len(data):
        length, kind = struct.unpack(">I4s", data[at:at + 8])
        found.setdefault(kind, at)
        at += 12 + length
    return found


def test_a_png_whose_chunk_runs_past_its_end_is_refused_before_it_is_decoded(tmp_path, capsys):
    """A 130-byte label PNG whose IDAT length a damaged byte made 3.6 GB: OpenCV refused it, but only after libpng
    had reserved what the chunk declared (3 s, most of it the kernel's, and as much memory). It is refused from its
    chunks' lengths now, naming the chunk, as palette PNGs already were; a PNG cut short anywhere is refused the
    same way, and one of many IDAT chunks reads as before."""
    import struct

    from pcreg.errors import InputError
    from pcreg.formats import decode_image

    rng = np.random.default_rng(0)
    labels = rng.integers(0, 3, (24, 32), dtype=np.uint8)
    data = cv2.imencode(".png", labels)[1].tobytes()
    idat = _chunks(data)[b"IDAT"]
    damaged = data[:idat] + struct.pack(">I", 0xD5722CBC) + data[idat + 4:]
    with pytest.raises(InputError, match=r"^key\.png: cannot decode image \(its 'IDAT' chunk runs past the end of the file: cut short\?\)$"):
        decode_image(damaged, "key.png")
    for kept, said in ((len(data) - 1, "ends before its IEND chunk"), (len(data) - 12, "ends before its IEND chunk"),
                       (idat + 20, "'IDAT' chunk runs past")):
        with pytest.raises(InputError, match=said):
            decode_image(data[:kept], "key.png")
    # a whole PNG of many IDAT chunks (libpng's writer splits at 8 kB) reads as it is
    big = rng.integers(0, 256, (256, 320, 3), dtype=np.uint8)
    many = cv2.imencode(".png", big, [cv2.IMWRITE_PNG_COMPRESSION, 0])[1].tobytes()
    assert np.array_equal(decode_image(many, "big.png"), big)
    # through the command line: one line naming the file, exit 2
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(2):
        cv2.imwrite(str(frames / f"f{i}.png"), rng.integers(0, 256, (24, 32, 3), dtype=np.uint8))
    key = tmp_path / "key.png"
    key.write_bytes(damaged)
    assert main(["run", str(frames), "--labels", str(key), "--out", str(tmp_path / "out")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"{key}: cannot decode image (its 'IDAT' chunk runs past the end of the file" in err[0], err


def test_16_bit_frames_holding_8_bit_values_are_said_once(tmp_path, capsys):
    """8-bit values stored in 16-bit PNGs read as nearly black (16 bits are scaled by 1/257): the run labelled
    them from little more than noise, exit 0, without a word, where ``pcreg register`` names the cause. Frames
    that use their 16 bits are read without a note."""
    for name, scale in (("low", 1), ("full", 257)):
        frames = tmp_path / name
        frames.mkdir()
        for i in range(3):
            cv2.imwrite(str(frames / f"f{i:02d}.png"), _scene(i).astype(np.uint16) * scale)
        assert main(["run", str(frames), "--labels", str(_key(tmp_path / "key.png")), "--out", str(tmp_path / f"out-{name}")]) == 0
        notes = [ln for ln in capsys.readouterr().err.splitlines() if "16-bit values" in ln]
        state = json.loads((tmp_path / f"out-{name}" / "run.json").read_text())
        if name == "full":
            assert notes == [] and "dark" not in (state.get("notes") or {})
            continue
        assert len(notes) == 1, notes
        assert notes[0].startswith(f"pcreg: note: {frames / 'f00.png'}: its 16-bit values lie in ") and "(nearly black)" in notes[0]
        assert state["notes"]["dark"] == notes[0].removeprefix("pcreg: note: ")
