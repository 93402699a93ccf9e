"""pcreg.datasets: synthetic sequences, LAGR .mat folders, image folders (CamVid)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import scipy.io

from pcreg.datasets import (
    CAMVID_MAPPING,
    SYNTHETIC_PRESETS,
    Frame,
    load_dataset,
    load_folder,
    load_lagr,
    relative_transform,
    synthetic,
)
from pcreg.errors import DatasetError, InputError

W, H = 96, 72


# -- Frame ----------------------------------------------------------------------------------------

def test_frame_is_read_only_view_and_leaves_inputs_alone():
    img = np.zeros((4, 5, 3), np.uint8)
    lab = np.ones((4, 5), np.uint8)
    f = Frame(image=img, labels=lab, name="a")
    assert f.shape == (4, 5) and f.labelled
    with pytest.raises(ValueError, match="read-only"):
        f.image[0, 0, 0] = 1
    img[0, 0, 0] = 7  # the caller's array stays writable and shared
    assert f.image[0, 0, 0] == 7
    assert "Frame(name='a'" in repr(f)


@pytest.mark.parametrize("image, labels", [
    (np.zeros((4, 5), np.uint8), None),
    (np.zeros((4, 5, 3), np.float32), None),
    (np.zeros((4, 5, 3), np.uint8), np.zeros((4, 6), np.uint8)),
    (np.zeros((4, 5, 3), np.uint8), np.full((4, 5), 3, np.int16)),
])
def test_frame_rejects_bad_arrays(image, labels):
    with pytest.raises(InputError):
        Frame(image=image, labels=labels, name="bad")


def test_frame_takes_any_class_ids():
    """A frame's labels are class ids of any table (CamVid's eleven and void here); the classifier checks
    them against its own table."""
    lab = np.arange(20, dtype=np.uint8).reshape(4, 5) % 12
    assert Frame(np.zeros((4, 5, 3), np.uint8), lab, "camvid").labels.max() == 11


def test_relative_transform_needs_poses():
    a = Frame(np.zeros((2, 2, 3), np.uint8), None, "a")
    assert relative_transform(a, a) is None
    b = Frame(np.zeros((2, 2, 3), np.uint8), None, "b", pose=np.diag([2.0, 2.0, 1.0]))
    np.testing.assert_allclose(relative_transform(b, b), np.eye(3), atol=1e-12)


# -- synthetic ------------------------------------------------------------------------------------

def test_presets_mirror_the_six_lagr_sets():
    assert len(SYNTHETIC_PRESETS) == 6 and len(set(SYNTHETIC_PRESETS)) == 6
    with pytest.raises(InputError, match="unknown synthetic preset"):
        synthetic("ds9z", 2)


@pytest.mark.parametrize("name", SYNTHETIC_PRESETS)
def test_synthetic_frames_are_well_formed(name):
    frames = synthetic(name, 6, 0, width=W, height=H)
    assert len(frames) == 6 and len({f.name for f in frames}) == 6
    for f in frames:
        assert f.image.shape == (H, W, 3) and f.image.dtype == np.uint8
        assert f.labels.shape == (H, W) and set(np.unique(f.labels)) <= {0, 1, 2}
        assert f.pose.shape == (3, 3)
        # no black border: every edge row/column has real content
        for edge in (f.image[0], f.image[-1], f.image[:, 0], f.image[:, -1]):
            assert edge.max() > 20
    lab = np.stack([f.labels for f in frames])
    for c in (0, 1, 2):
        assert (lab == c).mean() > 0.03, f"label {c} nearly absent"


def test_synthetic_is_deterministic_and_seeded():
    a = synthetic("syn2a", 4, 3, width=W, height=H)
    b = synthetic("syn2a", 4, 3, width=W, height=H)
    c = synthetic("syn2a", 4, 4, width=W, height=H)
    for fa, fb in zip(a, b):
        np.testing.assert_array_equal(fa.image, fb.image)
        np.testing.assert_array_equal(fa.pose, fb.pose)
    assert any(not np.array_equal(fa.image, fc.image) for fa, fc in zip(a, c))


def test_two_lightings_share_the_scene_but_not_the_colours():
    easy = synthetic("syn1a", 3, 0, width=W, height=H)
    hard = synthetic("syn1b", 3, 0, width=W, height=H)
    for e, h in zip(easy, hard):
        np.testing.assert_array_equal(e.labels, h.labels)
        np.testing.assert_array_equal(e.pose, h.pose)
        assert np.abs(e.image.astype(int) - h.image.astype(int)).mean() > 10


@pytest.mark.parametrize("name", ["syn1a", "syn2a"])
def test_synthetic_poses_are_the_ground_truth(name):
    """Warping frame k into frame 0 with T_ref_mov lines up the labels (and colours) exactly."""
    frames = synthetic(name, 12, 0, width=160, height=120)
    ref, mov = frames[0], frames[11]
    t_ref_mov = relative_transform(ref, mov)
    assert not np.allclose(t_ref_mov, np.eye(3), atol=1e-3)  # the camera moved
    # dst(x_ref) = mov(T_mov_ref x_ref): warpAffine with the inverse map
    t_mov_ref = np.linalg.inv(t_ref_mov)
    lab = cv2.warpAffine(mov.labels, t_mov_ref[:2], (160, 120), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                         borderValue=255)
    valid = lab != 255
    assert valid.mean() > 0.7
    agree = (lab[valid] == ref.labels[valid]).mean()
    unwarped = (mov.labels == ref.labels).mean()
    assert agree > 0.97 and agree > unwarped


def test_synthetic_default_size_is_640x480():
    frames = synthetic("syn3b", 2, 11)
    assert frames[0].image.shape == (480, 640, 3) and frames[0].labels.shape == (480, 640)


# -- LAGR -----------------------------------------------------------------------------------------

def _write_lagr(folder: Path, n: int, *, rng, masks: bool = True, names=None) -> list[tuple]:
    folder.mkdir(parents=True)
    out = []
    for i in range(n):
        img = rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)  # (H, W, 3)
        lab = rng.integers(0, 3, (6, 8)).astype(np.uint8)
        data = {"im_rgb": np.moveaxis(img, 0, 1)}  # stored transposed: W x H x 3
        if masks:
            data["manual_human_labeling_mask"] = np.moveaxis(lab, 0, 1).astype(np.float64)
        name = names[i] if names else f"frame{i + 1:03d}.mat"
        scipy.io.savemat(folder / name, data)
        out.append((img, lab if masks else None))
    return out


def test_load_lagr_reads_the_transposed_layout(tmp_path):
    rng = np.random.default_rng(0)
    truth = _write_lagr(tmp_path / "labeled_lagr_data_640x480_DS1A", 3, rng=rng)
    frames = load_lagr(tmp_path / "labeled_lagr_data_640x480_DS1A")
    assert [f.name for f in frames] == ["frame001", "frame002", "frame003"]
    for f, (img, lab) in zip(frames, truth):
        np.testing.assert_array_equal(f.image, img)
        np.testing.assert_array_equal(f.labels, lab)
        assert f.pose is None


def test_load_lagr_orders_frames_by_number(tmp_path):
    rng = np.random.default_rng(1)
    _write_lagr(tmp_path / "s", 3, rng=rng, names=["frame10.mat", "frame2.mat", "frame1.mat"])
    assert [f.name for f in load_lagr(tmp_path / "s")] == ["frame1", "frame2", "frame10"]


def test_supplemental_frames_load_unlabelled(tmp_path):
    rng = np.random.default_rng(2)
    folder = tmp_path / "labeled_lagr_data_640x480_DS1A_SupplementalFrames_101-303"
    truth = _write_lagr(folder, 2, rng=rng, masks=False)
    frames = load_lagr(folder)
    assert all(f.labels is None for f in frames)
    np.testing.assert_array_equal(frames[1].image, truth[1][0])


def test_load_dataset_finds_every_lagr_set(tmp_path):
    rng = np.random.default_rng(3)
    _write_lagr(tmp_path / "labeled_lagr_data_640x480_DS1A", 2, rng=rng)
    _write_lagr(tmp_path / "labeled_lagr_data_640x480_DS2B", 3, rng=rng)
    data = load_dataset(f"lagr:{tmp_path}")
    assert {k: len(v) for k, v in data.items()} == {"DS1A": 2, "DS2B": 3}


def test_lagr_errors(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="no .mat frames"):
        load_lagr(tmp_path / "empty")
    (tmp_path / "novars").mkdir()
    scipy.io.savemat(tmp_path / "novars" / "frame001.mat", {"something": np.zeros(3)})
    with pytest.raises(DatasetError, match="im_rgb"):
        load_lagr(tmp_path / "novars")
    rng = np.random.default_rng(4)
    _write_lagr(tmp_path / "mixed", 2, rng=rng)
    scipy.io.savemat(tmp_path / "mixed" / "frame003.mat", {"im_rgb": np.zeros((8, 6, 3), np.uint8)})
    with pytest.raises(DatasetError, match="manual_human_labeling_mask"):
        load_lagr(tmp_path / "mixed")
    (tmp_path / "badmask").mkdir()
    scipy.io.savemat(tmp_path / "badmask" / "frame001.mat",
                     {"im_rgb": np.zeros((8, 6, 3), np.uint8), "manual_human_labeling_mask": np.full((8, 6), 5.0)})
    with pytest.raises(DatasetError, match="outside"):
        load_lagr(tmp_path / "badmask")
    (tmp_path / "emptyimage").mkdir()  # was read, then refused as "image is empty: (0, 0, 3)", naming no file
    scipy.io.savemat(tmp_path / "emptyimage" / "frame001.mat",
                     {"im_rgb": np.zeros((0, 0, 3), np.uint8), "manual_human_labeling_mask": np.zeros((0, 0), np.uint8)})
    with pytest.raises(DatasetError, match=r"frame001.mat: im_rgb is 0 x 0 x 3: an empty image"):
        load_lagr(tmp_path / "emptyimage")
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "frame001.mat").write_bytes(b"not a mat file at all")
    with pytest.raises(DatasetError, match="cannot read"):
        load_lagr(tmp_path / "broken")


# -- image folders --------------------------------------------------------------------------------

def _write_clip(folder: Path, n: int, *, rng, ids=tuple(range(12)), size=(10, 8)) -> list[tuple]:
    (folder / "images").mkdir(parents=True)
    (folder / "labels").mkdir()
    out = []
    for i in range(n):
        img = rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)
        raw = rng.choice(np.array(ids, np.uint8), (size[1], size[0]))
        cv2.imwrite(str(folder / "images" / f"f{i:02d}.png"), cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        cv2.imwrite(str(folder / "labels" / f"f{i:02d}.png"), raw)
        out.append((img, raw))
    return out


def test_load_folder_maps_camvid_ids(tmp_path):
    truth = _write_clip(tmp_path / "clip", 3, rng=np.random.default_rng(5))
    frames = load_folder(tmp_path / "clip", mapping="camvid")
    lut = np.array([CAMVID_MAPPING[i] for i in range(12)], np.uint8)
    for f, (img, raw) in zip(frames, truth):
        np.testing.assert_array_equal(f.image, img)
        np.testing.assert_array_equal(f.labels, lut[raw])


def test_a_folder_frame_decoded_around_damaged_data_is_marked(tmp_path):
    """A CamVid-like clip whose JPEG frame is cut short (its end marker put back): the frame is the decoder's
    guess in part; the frame says so (:attr:`Frame.damage`), as ``pcreg register`` does of such an image."""
    from pcreg.datasets.frame import damage_notes

    _write_clip(tmp_path / "data" / "clip", 2, rng=np.random.default_rng(5), ids=(0, 1, 2), size=(64, 48))
    for i in range(2):
        png = tmp_path / "data" / "clip" / "images" / f"f{i:02d}.png"
        cv2.imwrite(str(png.with_suffix(".jpg")), cv2.imread(str(png)))
        png.unlink()
    jpg = tmp_path / "data" / "clip" / "images" / "f01.jpg"
    data = jpg.read_bytes()
    jpg.write_bytes(data[:len(data) * 2 // 3] + b"\xff\xd9")
    data = load_dataset(f"folder:{tmp_path / 'data'}")
    assert [f.damage[:17] for f in data["clip"]] == ["", "Corrupt JPEG data"]
    (line,) = damage_notes(data)
    assert line.startswith("clip clip, frame f01: its decoder reports damaged data (Corrupt JPEG data")


def test_folder_frames_with_transparent_pixels_or_dark_16_bit_values_are_noted(tmp_path):
    """Frames an evaluation scores with figures that may be off were scored without a word, where ``pcreg run``
    notes them: transparent pixels (alpha left out), 8-bit values stored in 16 bits (read as nearly black)."""
    from pcreg.datasets.frame import damage_notes

    _write_clip(tmp_path / "data" / "clip", 5, rng=np.random.default_rng(5), ids=(0, 1, 2), size=(64, 48))
    images = tmp_path / "data" / "clip" / "images"
    bgr = cv2.imread(str(images / "f01.png"))
    cv2.imwrite(str(images / "f01.png"), np.dstack([bgr, np.full(bgr.shape[:2], 255, np.uint8)]))  # opaque: no note
    bgra = np.dstack([bgr, np.full(bgr.shape[:2], 255, np.uint8)])
    bgra[:4, :, 3] = 0
    cv2.imwrite(str(images / "f02.png"), bgra)
    for name in ("f03", "f04"):
        cv2.imwrite(str(images / f"{name}.png"), cv2.imread(str(images / f"{name}.png")).astype(np.uint16))
    data = load_dataset(f"folder:{tmp_path / 'data'}")
    assert [len(f.notes) for f in data["clip"]] == [0, 0, 1, 1, 1]
    assert data["clip"][1].image.tobytes() == bgr[:, :, ::-1].tobytes()
    lines = damage_notes(data, said=2)
    assert len(lines) == 3
    assert lines[0].startswith(f"clip clip, frame f02: {images / 'f02.png'} has transparent pixels (256 of its 3072")
    assert lines[1].startswith(f"clip clip, frame f03: {images / 'f03.png'}: its 16-bit values lie in ")
    assert lines[1].endswith("(the figures of the frames it is in may be off)")
    assert lines[2] == "1 more frame(s) read with such notes"


@pytest.mark.parametrize("where", ["images", "labels"])
@pytest.mark.parametrize("what", ["a link to nothing", "a folder"])
def test_an_entry_named_as_a_frame_that_is_no_file_is_named(tmp_path, where, what):
    """A link to nothing (or a folder) named ``f02.png`` among a clip's frames or labels was left out, and the
    refusal then said "label file without an image" or "no label file": the file was there."""
    _write_clip(tmp_path / "data" / "clip", 2, rng=np.random.default_rng(5), ids=(0, 1, 2))
    bad = tmp_path / "data" / "clip" / where / "f02.png"
    if what == "a folder":
        bad.mkdir()
    else:
        bad.symlink_to(tmp_path / "gone.png")
    with pytest.raises(DatasetError) as err:
        load_dataset(f"folder:{tmp_path / 'data'}")
    assert str(err.value).startswith(f"{bad}: named as a ") and "not a file that can be read" in str(err.value)


def test_a_folder_of_camvid_ids_is_refused_naming_the_data_spelling_that_reads_them(tmp_path):
    """``--data folder:`` of CamVid's ids: the refusal named ``--mapping camvid``, which ``evaluate`` does not take;
    it names ``--data camvid:`` too, and says whose option ``--mapping`` is."""
    _write_clip(tmp_path / "data" / "clip", 2, rng=np.random.default_rng(7))
    with pytest.raises(DatasetError, match=r"f00\.png: label value \d+ is not a class id .* pcreg run's --mapping "
                       r"camvid, and --data camvid:, read CamVid's ids as ground and obstacle"):
        load_dataset(f"folder:{tmp_path / 'data'}")


def test_load_folder_with_dict_mapping_and_without_labels(tmp_path):
    truth = _write_clip(tmp_path / "c", 2, rng=np.random.default_rng(6), ids=(7, 9))
    frames = load_folder(tmp_path / "c", mapping={7: 0, 9: 1})
    np.testing.assert_array_equal(frames[0].labels, (truth[0][1] == 9).astype(np.uint8))
    for p in (tmp_path / "c" / "labels").iterdir():
        p.unlink()
    (tmp_path / "c" / "labels").rmdir()
    assert all(f.labels is None for f in load_folder(tmp_path / "c"))


@pytest.mark.parametrize("damage, message", [
    ("no_images", "no image frames"),
    ("image_without_label", "no label file"),
    ("label_without_image", "label file without an image"),
    ("size_mismatch", "but the image is"),
    ("ids_outside_mapping", "label value 40 is not a class id"),
    ("corrupt_png", "cannot decode"),
])
def test_load_folder_errors(tmp_path, damage, message):
    clip = tmp_path / "clip"
    _write_clip(clip, 2, rng=np.random.default_rng(7))
    if damage == "no_images":
        for p in (clip / "images").iterdir():
            p.unlink()
    elif damage == "image_without_label":
        (clip / "labels" / "f01.png").unlink()
    elif damage == "label_without_image":
        (clip / "images" / "f01.png").unlink()
    elif damage == "size_mismatch":
        cv2.imwrite(str(clip / "labels" / "f01.png"), np.zeros((5, 5), np.uint8))
    elif damage == "ids_outside_mapping":
        cv2.imwrite(str(clip / "labels" / "f01.png"), np.full((8, 10), 40, np.uint8))
    elif damage == "corrupt_png":
        (clip / "images" / "f01.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(DatasetError, match=message) as err:
        load_folder(clip)
    assert "\n" not in str(err.value)


def test_load_folder_refuses_frames_whose_name_order_is_not_their_count(tmp_path):
    """f10.png sorts before f9.png: read in name order, the key frame would be f10 and f9 scored after f11."""
    clip = tmp_path / "clip"
    _write_clip(clip, 3, rng=np.random.default_rng(8))
    for sub in ("images", "labels"):
        for old, new in (("f00", "f9"), ("f01", "f10"), ("f02", "f11")):
            (clip / sub / f"{old}.png").rename(clip / sub / f"{new}.png")
    with pytest.raises(DatasetError, match="numbered with different widths") as err:
        load_folder(clip)
    assert str(clip / "images") in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(DatasetError, match="numbered with different widths"):
        load_dataset(f"camvid:{clip}")


def test_load_dataset_specs(tmp_path):
    with pytest.raises(InputError, match="unknown kind 'nonsense'"):
        load_dataset("nonsense:/x")
    with pytest.raises(InputError, match="size must be"):
        load_dataset("synthetic:syn1a", n_frames=1, size=(48, 36, 3))
    with pytest.raises(InputError, match="n_frames must be an integer"):
        load_dataset("synthetic:syn1a", n_frames=2.5, size=(48, 36))
    with pytest.raises(DatasetError, match="no such folder"):
        load_dataset(f"camvid:{tmp_path / 'missing'}")
    data = load_dataset("synthetic:syn1a,syn3b", n_frames=2, size=(48, 36))
    assert list(data) == ["syn1a", "syn3b"] and data["syn3b"][0].image.shape == (36, 48, 3)
    assert list(load_dataset("synthetic", n_frames=1, size=(32, 24))) == list(SYNTHETIC_PRESETS)


def test_a_frame_size_for_real_frames_is_refused_not_ignored(tmp_path):
    """``size`` sets synthetic frames' size only: given for real frames (which keep their own) it is bad input,
    not ignored (the commands' side: tests/test_evaluate_size.py)."""
    (tmp_path / "data" / "clip" / "images").mkdir(parents=True)
    with pytest.raises(InputError, match="--size 12x10 sets synthetic frames' size only"):
        load_dataset(f"folder:{tmp_path / 'data'}", size=(12, 10))


@pytest.mark.data
def test_camvid_clips_load(shared_data):
    camvid = shared_data / "camvid"
    if not camvid.is_dir():
        pytest.skip(f"{camvid} is absent")
    data = load_dataset(f"camvid:{camvid}")
    assert {"0001TP", "0006R0", "0016E5", "Seq05VD"} <= set(data)
    assert len(data["0016E5"]) == 60 and len(data["0001TP"]) == 30
    f = data["0016E5"][0]
    assert f.image.shape == (360, 480, 3) and f.labels.shape == (360, 480)
    lab = np.concatenate([fr.labels.ravel() for fr in data["0001TP"]])
    assert set(np.unique(lab)) == {0, 1, 2}
    one = load_dataset(f"camvid:{camvid / '0006R0'}")
    assert list(one) == ["0006R0"]


@pytest.mark.parametrize("kind", ["camvid", "folder", "davis"])
def test_a_clip_whose_frames_folder_is_missing_is_refused_not_passed_over(tmp_path, kind):
    """A folder of clips (or DAVIS sequences) one of which holds labels/ but its frames under another name, or behind a
    link to nowhere: refused naming its images/ (before, it was passed over and the others scored without a word)."""
    rng = np.random.default_rng(3)
    ids = {"davis": (0, 1), "folder": (0, 1, 2)}.get(kind, tuple(range(12)))
    for name in ("a", "b"):
        _write_clip(tmp_path / "root" / name, 3, rng=rng, ids=ids)
    assert sorted(load_dataset(f"{kind}:{tmp_path / 'root'}")) == ["a", "b"]
    (tmp_path / "root" / "b" / "images").rename(tmp_path / "root" / "b" / "frames")
    with pytest.raises(DatasetError) as err:
        load_dataset(f"{kind}:{tmp_path / 'root'}")
    assert str(err.value).startswith(f"{tmp_path / 'root' / 'b' / 'images'}: no such folder, beside ") \
        and "if frames/ holds them, name it images/" in str(err.value)
    (tmp_path / "root" / "b" / "images").symlink_to(tmp_path / "gone")
    with pytest.raises(DatasetError, match="images: a link to nowhere, beside "):
        load_dataset(f"{kind}:{tmp_path / 'root'}")


@pytest.mark.parametrize("kind", ["camvid", "davis"])
def test_a_downloads_archive_given_as_the_folder_is_told_to_be_unpacked(tmp_path, kind):
    import zipfile

    archive = tmp_path / "download.zip"
    with zipfile.ZipFile(archive, "w") as z:
        z.writestr("clip/images/f00.png", b"")
    with pytest.raises(DatasetError, match=r"download\.zip: an archive, not a folder: unpack it and give the folder"):
        load_dataset(f"{kind}:{archive}")
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(DatasetError, match=r"notes\.txt: a file, not a folder of frames"):
        load_dataset(f"{kind}:{tmp_path / 'notes.txt'}")
    with pytest.raises(DatasetError, match=r"nothing: no such folder"):
        load_dataset(f"{kind}:{tmp_path / 'nothing'}")


@pytest.mark.parametrize("kind", ["camvid", "davis"])
def test_a_label_saved_as_a_jpeg_is_named_in_the_refusal_of_its_missing_png(tmp_path, kind):
    rng = np.random.default_rng(4)
    _write_clip(tmp_path / "root" / "a", 3, rng=rng, ids=(0, 1) if kind == "davis" else tuple(range(12)))
    label = tmp_path / "root" / "a" / "labels" / "f01.png"
    cv2.imwrite(str(label.with_suffix(".jpg")), cv2.imread(str(label)))
    label.unlink()
    with pytest.raises(DatasetError, match=r"; labels/f01\.jpg is there, but a label is read from a PNG only"):
        load_dataset(f"{kind}:{tmp_path / 'root'}")


def test_a_grey_frame_among_colour_frames_is_noted(tmp_path):
    """A frame saved as grey in a colour clip was scored without a word (the colour features read it otherwise:
    CamVid 0001TP_b's classification error 16.8% -> 21.5%); a clip all grey says nothing."""
    from pcreg.datasets.frame import damage_notes

    _write_clip(tmp_path / "data" / "clip", 4, rng=np.random.default_rng(5), ids=(0, 1, 2), size=(64, 48))
    images = tmp_path / "data" / "clip" / "images"
    cv2.imwrite(str(images / "f02.png"), cv2.imread(str(images / "f02.png"), cv2.IMREAD_GRAYSCALE))
    data = load_dataset(f"folder:{tmp_path / 'data'}")
    assert damage_notes(data) == ["clip clip, frame f02: grey among the clip's colour frames (its three colours equal "
                                  "at every pixel: saved as grey, or black): the colour features read it otherwise "
                                  "than the frames around it, and the figures of the frames it is in may be off"]
    for p in images.iterdir():
        cv2.imwrite(str(p), cv2.imread(str(p), cv2.IMREAD_GRAYSCALE))
    assert damage_notes(load_dataset(f"folder:{tmp_path / 'data'}")) == []
