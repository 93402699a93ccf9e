"""DAVIS sequences (pcreg.datasets.davis): both layouts, one sequence or a folder of them, the published
results beside them or shipped, and bad sequences refused naming the file."""

from __future__ import annotations

import shutil

import cv2
import numpy as np
import pytest

from pcreg.datasets import load_dataset
from pcreg.datasets.davis import PUBLISHED_CSV, PUBLISHED_SOURCE, find_sequences, load_davis, published
from pcreg.errors import DatasetError
from _davis import frames_and_masks, shared_sequence, write_official_layout, write_palette, write_pcreg_layout


def _same(a, b) -> None:
    assert list(a) == list(b)
    for name in a:
        assert [f.name for f in a[name]] == [f.name for f in b[name]]
        for fa, fb in zip(a[name], b[name]):
            np.testing.assert_array_equal(fa.image, fb.image)
            np.testing.assert_array_equal(fa.labels, fb.labels)


def test_both_layouts_one_sequence_or_a_folder_give_the_same_frames(tmp_path):
    pairs = frames_and_masks(4)
    ours = tmp_path / "ours"
    write_pcreg_layout(ours / "disc", pairs)
    write_pcreg_layout(ours / "disc2", pairs[:3])
    root = write_official_layout(tmp_path / "DAVIS", "disc", pairs)
    write_official_layout(root, "disc2", pairs[:3])
    folder = load_dataset(f"davis:{ours}")
    assert list(folder) == ["disc", "disc2"] and len(folder["disc"]) == 4 and len(folder["disc2"]) == 3
    for spec in (f"davis:{root}", f"davis:{root}/JPEGImages/480p"):
        _same(load_dataset(spec), folder)
    one = load_dataset(f"davis:{root}/JPEGImages/480p/disc")
    _same(one, load_dataset(f"davis:{ours}/disc"))
    assert list(one) == ["disc"]
    f = one["disc"][0]
    assert f.name == "00000" and f.labels.dtype == np.uint8 and set(np.unique(f.labels)) == {0, 1}
    np.testing.assert_array_equal(f.labels, pairs[0][1] > 0)  # 0 the background, anything else the object
    assert len(load_dataset(f"davis:{ours}/disc", n_frames=2)["disc"]) == 2
    # where the published results are looked for: beside the sequences
    assert find_sequences(ours / "disc")[1] == ours and find_sequences(ours)[1] == ours
    for p in (root, root / "JPEGImages" / "480p", root / "JPEGImages" / "480p" / "disc"):
        assert find_sequences(p)[1] == root


def test_another_resolution_folder_and_a_palette_mask_are_read(tmp_path):
    pairs = frames_and_masks(3)
    root = write_official_layout(tmp_path / "DAVIS", "disc", pairs, resolution="Full-Resolution")
    colour = np.zeros((*pairs[1][1].shape, 3), np.uint8)
    colour[pairs[1][1] > 0] = (0, 0, 128)  # DAVIS 2017's masks are palette images: object 1 is dark red
    cv2.imwrite(str(root / "Annotations" / "Full-Resolution" / "disc" / "00001.png"), colour)
    frames = load_davis(root)["disc"]
    np.testing.assert_array_equal(frames[1].labels, pairs[1][1] > 0)


@pytest.mark.data
def test_a_shared_sequence_in_the_official_layout_reads_as_in_pcregs(shared_data, tmp_path):
    goat = shared_sequence(shared_data, "goat")
    root = tmp_path / "DAVIS"
    for sub, dst in (("images", "JPEGImages"), ("labels", "Annotations")):
        (root / dst / "480p" / "goat").mkdir(parents=True)
        for i in range(3):
            name = f"{i:05d}" + (".jpg" if sub == "images" else ".png")
            (root / dst / "480p" / "goat" / name).write_bytes((goat / sub / name).read_bytes())
    _same(load_davis(root), load_davis(goat, n_frames=3))
    assert load_davis(root)["goat"][0].shape == (480, 854)


def test_an_official_layout_beside_sequences_in_pcregs_is_refused_naming_both(tmp_path):
    """A folder of DAVIS's official layout that also holds a sequence in pcreg's (SEQ/images/) was read as the
    official layout alone: the other sequence was left out without a word."""
    root = write_official_layout(tmp_path / "DAVIS", "goat", frames_and_masks(3))
    write_pcreg_layout(root / "myseq", frames_and_masks(3, seed=1))
    with pytest.raises(DatasetError, match=r"DAVIS: holds DAVIS's official layout \(JPEGImages/480p/\) and sequences "
                                           r"in pcreg's \(myseq: SEQ/images/\): give davis:.*JPEGImages/480p"):
        load_davis(root)
    assert list(load_davis(root / "JPEGImages" / "480p")) == ["goat"]
    assert list(load_davis(root / "myseq")) == ["myseq"]
    shutil.rmtree(root / "myseq")  # the other way round: ROOT/images/ was read as one sequence, the official ones left out
    write_pcreg_layout(root, frames_and_masks(3, seed=1))
    with pytest.raises(DatasetError, match=r"DAVIS: a sequence in pcreg's layout \(images/\) and DAVIS's official layout "
                                           r"\(JPEGImages/480p/\) in one folder"):
        load_davis(root)


def test_the_published_results_beside_the_sequences_or_pcregs_own(tmp_path):
    ours = tmp_path / "ours"
    write_pcreg_layout(ours / "blackswan", frames_and_masks(3))
    shipped = published(ours)
    assert shipped["file"] == str(PUBLISHED_CSV) and shipped["source"] == PUBLISHED_SOURCE
    assert shipped["methods"] == ["osvos", "msk", "ofl", "bvs", "fcp", "jmp", "hvs", "sea", "tsp"]
    assert len(shipped["J"]["osvos"]) == 20  # DAVIS 2016 val
    assert shipped["J"]["osvos"]["blackswan"] == 0.9423 and shipped["F"]["tsp"]["breakdance"] == 0.0699
    # the means over the twenty sequences are the website's (json_data/global_eval_val_2016.js)
    for m, j, f in (("osvos", 0.798, 0.806), ("ofl", 0.680, 0.634), ("bvs", 0.600, 0.588), ("tsp", 0.319, 0.297)):
        assert np.mean(list(shipped["J"][m].values())) == pytest.approx(j, abs=6e-4)
        assert np.mean(list(shipped["F"][m].values())) == pytest.approx(f, abs=6e-4)
    # a file beside them with the same figures is cited as the website's; other figures as the file's own
    (ours / "published_mine.csv").write_text("method,sequence,J_mean,F_mean\nosvos,blackswan,0.9423,0.9753\n")
    beside = published(ours)
    assert beside["file"].endswith("published_mine.csv") and beside["source"] == PUBLISHED_SOURCE
    assert beside["methods"] == ["osvos"]
    # two figures of one method and sequence (two files, or one file twice): refused naming both lines; the same twice is one
    (ours / "published_more.csv").write_text("method,sequence,J_mean,F_mean\nosvos,blackswan,0.1,0.1\n")
    with pytest.raises(DatasetError, match=r"published_more.csv: line 2: osvos on blackswan has J 0.1, F 0.1 here and "
                                           r"J 0.9423, F 0.9753 at .*published_mine.csv: line 2: one figure each"):
        published(ours)
    (ours / "published_more.csv").write_text("# the same\nmethod,sequence,J_mean,F_mean\nosvos,blackswan,0.9423,0.9753\n")
    assert published(ours)["J"]["osvos"] == {"blackswan": 0.9423}
    (ours / "published_more.csv").unlink()
    (ours / "published_mine.csv").write_text("method,sequence,J_mean,F_mean\nmine,blackswan,0.5,0.4\nmine,blackswan,0.5,0.4000001\n")
    with pytest.raises(DatasetError, match=r"published_mine.csv: line 3: mine on blackswan has J 0.5, F 0.4000001 here "
                                           r"and J 0.5, F 0.4 at"):  # every digit shown: what differs can be seen
        published(ours)
    (ours / "published_mine.csv").write_text("method,sequence,J_mean,F_mean,n_frames_evaluated\nmine,blackswan,nan,nan,48\n"
                                             "mine,blackswan,nan,nan,48\nmine,blackswan,nan,nan,10\n")
    with pytest.raises(DatasetError, match=r"line 4: mine on blackswan has J nan, F nan, 10 frames here and J nan, F nan, "
                                           r"48 frames at .*line 2"):  # NaN twice is the same figure; frames count
        published(ours)
    (ours / "published_mine.csv").write_text("method,sequence,J_mean,F_mean\nmine,blackswan,0.5,0.4\n")
    assert published(ours)["source"] == "published_mine.csv (which names no source)"
    (ours / "published_mine.csv").write_text("method,sequence,J_mean,F_mean\n# nothing yet\n")  # the columns went
    with pytest.raises(DatasetError, match="published_mine.csv: no published figure, its header alone"):
        published(ours)
    (ours / "published_mine.csv").write_text("method,sequence,J\nmine,blackswan,0.5\n")
    with pytest.raises(DatasetError, match="published_mine.csv: published results need the columns"):
        published(ours)


@pytest.mark.data
def test_the_shared_published_csv_is_the_figures_pcreg_ships(shared_data):
    if not (shared_data / "davis" / "published_val2016_shared.csv").is_file():
        pytest.skip("../shared/data/davis/published_val2016_shared.csv is absent")
    doc = published(shared_data / "davis")
    assert doc["source"] == PUBLISHED_SOURCE and len(doc["methods"]) == 9
    assert set(doc["J"]["bvs"]) == {"blackswan", "breakdance", "car-roundabout", "goat", "kite-surf"}


def _broken(tmp_path, how: str):
    """A pcreg-layout sequence broken one way; the file its message must name."""
    seq = write_pcreg_layout(tmp_path / "seq", frames_and_masks(4))
    if how == "a mask of another size":
        cv2.imwrite(str(seq / "labels" / "00002.png"), np.zeros((24, 32), np.uint8))
        return seq, seq / "labels" / "00002.png", "the mask is 32x24, its frame 00002.jpg 64x48"
    if how == "no first mask":
        (seq / "labels" / "00000.png").unlink()
        return seq, seq / "labels" / "00000.png", "no mask of the first frame"
    if how == "an empty key mask":
        cv2.imwrite(str(seq / "labels" / "00000.png"), np.zeros((48, 64), np.uint8))
        return seq, seq / "labels" / "00000.png", "the object's mask on the key frame is empty"
    if how == "an unreadable JPEG":
        path = seq / "images" / "00001.jpg"
        path.write_bytes(path.read_bytes()[:200])
        return seq, path, "cannot decode image"
    if how == "masks read two ways":  # a first mask of two objects by palette index, later ones DAVIS 2016's 0/255
        first = cv2.imread(str(seq / "labels" / "00000.png"), cv2.IMREAD_GRAYSCALE)
        ids = (first > 0).astype(np.uint8)
        ids[:6, :6] = 2
        write_palette(seq / "labels" / "00000.png", ids)
        return seq, seq / "labels" / "00001.png", "a grey mask of one object (0 and 255, DAVIS 2016's) after a first mask of 2"
    (seq / "labels" / "00003.png").unlink()  # a later mask missing
    return seq, seq / "labels" / "00003.png", "no mask of frame 00003.jpg"


BROKEN = ("a mask of another size", "no first mask", "an empty key mask", "an unreadable JPEG", "masks read two ways",
          "a later mask missing")


@pytest.mark.parametrize("how", BROKEN)
def test_a_broken_sequence_is_refused_naming_the_file(tmp_path, how):
    seq, path, what = _broken(tmp_path, how)
    with pytest.raises(DatasetError) as err:
        load_dataset(f"davis:{seq}")
    assert str(err.value).startswith(f"{path}: ") and what in str(err.value)


def test_hidden_files_are_left_out_and_unpadded_numbers_refused_as_pcreg_run_does(tmp_path):
    """A folder copied from a Mac (``._00000.jpg`` beside each frame) was refused, which ``pcreg run`` reads; frames
    numbered ``0.jpg ... 11.jpg`` were scored in name order (``10.jpg`` after ``1.jpg``), which it refuses."""
    pairs = frames_and_masks(4)
    seq = write_pcreg_layout(tmp_path / "mac", pairs)
    for sub, suffix in (("images", ".jpg"), ("labels", ".png")):
        for i in range(4):
            (seq / sub / f"._{i:05d}{suffix}").write_bytes(b"\x00\x05\x16\x07" + bytes(60))  # AppleDouble
    plain = write_pcreg_layout(tmp_path / "plain", pairs)
    _same({"s": load_dataset(f"davis:{seq}")["mac"]}, {"s": load_dataset(f"davis:{plain}")["plain"]})
    unpadded = tmp_path / "unpadded"
    write_pcreg_layout(unpadded, frames_and_masks(11))
    for sub, suffix in (("images", ".jpg"), ("labels", ".png")):
        for i in range(11):
            (unpadded / sub / f"{i:05d}{suffix}").rename(unpadded / sub / f"{i}{suffix}")
    with pytest.raises(DatasetError) as err:
        load_dataset(f"davis:{unpadded}")
    assert str(err.value).startswith(f"{unpadded / 'images'}: frames numbered with different widths (10.jpg sorts")


def test_a_hidden_folder_beside_the_sequences_is_no_sequence(tmp_path):
    """A hidden folder among an official root's sequences (``.ipynb_checkpoints``, left by a notebook) was taken
    as a sequence and the root refused (no frames in it); hidden folders are left out as hidden files are."""
    pairs = frames_and_masks(4)
    root = write_official_layout(tmp_path / "root", "seq", pairs)
    plain = write_official_layout(tmp_path / "plain", "seq", pairs)
    (root / "JPEGImages" / "480p" / ".ipynb_checkpoints").mkdir()
    write_pcreg_layout(tmp_path / "folder" / ".trash", pairs)
    write_pcreg_layout(tmp_path / "folder" / "seq", pairs)
    _same(load_dataset(f"davis:{root}"), load_dataset(f"davis:{plain}"))
    _same(load_dataset(f"davis:{tmp_path / 'folder'}"), load_dataset(f"davis:{plain}"))


def test_a_frame_saved_both_as_jpg_and_png_is_refused_naming_it(tmp_path):
    """A sequence whose frames were converted to PNG beside their JPEGs was read with every frame twice
    (00000.jpg, 00000.png, 00001.jpg, ...): twice the frames, half of them no motion, scored silently."""
    seq = write_pcreg_layout(tmp_path / "seq", frames_and_masks(3))
    for i in range(3):
        jpg = seq / "images" / f"{i:05d}.jpg"
        cv2.imwrite(str(jpg.with_suffix(".png")), cv2.imread(str(jpg)))
    with pytest.raises(DatasetError) as err:
        load_dataset(f"davis:{seq}")
    assert str(err.value) == f"{seq / 'images' / '00000.jpg'}: a second frame of this name beside it, 00000.png; keep one"


def test_masks_with_an_upper_case_suffix_are_masks(tmp_path):
    """Masks saved as ``00000.PNG`` were refused as missing ('no mask of the first frame', naming ``00000.png``)
    while frames' upper-case suffixes were read."""
    pairs = frames_and_masks(3)
    seq = write_pcreg_layout(tmp_path / "upper", pairs)
    for p in (seq / "labels").iterdir():
        p.rename(p.with_suffix(".PNG"))
    plain = write_pcreg_layout(tmp_path / "plain", pairs)
    _same({"s": load_dataset(f"davis:{seq}")["upper"]}, {"s": load_dataset(f"davis:{plain}")["plain"]})


@pytest.mark.parametrize("missing", ["00002.jpg", "00003.jpg"])
def test_a_mask_without_its_frame_is_refused_naming_it(tmp_path, missing):
    """A frame missing from a sequence whose mask is there (a copy cut short) was skipped: the frames after it
    moved up one, the benchmark's frames 1 to n-2 were not the ones scored (the last frame's mask scored, or a
    frame's left out), and the motion between two frames doubled. DAVIS masks every frame: refused."""
    seq = write_pcreg_layout(tmp_path / "seq", frames_and_masks(4))
    (seq / "images" / missing).unlink()
    mask = seq / "labels" / missing.replace(".jpg", ".png")
    with pytest.raises(DatasetError) as err:
        load_dataset(f"davis:{seq}")
    assert str(err.value).startswith(f"{mask}: a mask without its frame")


def test_a_file_beside_the_sequences_with_figures_of_its_own_does_not_cite_them_as_the_websites(tmp_path):
    """A ``published_*.csv`` that held one row of the website's figures beside a method of its own (or a sequence
    pcreg ships no figure for) was cited whole as the DAVIS website's data: the tables said the other figures
    came from there. Only the figures checked against pcreg's copy carry that source."""
    ours = tmp_path / "ours"
    write_pcreg_layout(ours / "blackswan", frames_and_masks(3))
    (ours / "published_mine.csv").write_text("method,sequence,J_mean,F_mean\nosvos,blackswan,0.9423,0.9753\n"
                                             "mine,blackswan,0.5,0.4\nosvos,bear,0.9,0.9\n")
    doc = published(ours)
    assert doc["methods"] == ["osvos", "mine"]
    assert doc["source"] != PUBLISHED_SOURCE
    assert doc["source"] == (f"{PUBLISHED_SOURCE}, except the figures of mine, osvos that pcreg does not ship: "
                             "published_mine.csv (which names no source)")


def test_a_frame_missing_with_its_mask_is_noted(tmp_path):
    """A frame and its mask both missing from a sequence (a copy cut short) were read without a word: the frames
    after it scored against the benchmark's as if none were missing, the motion to the next one doubled. Noted on
    the frame after the gap (stderr and the report's ``data_notes``, as damaged frames are); numbered every frame,
    no note."""
    from pcreg.datasets.frame import damage_notes

    seq = write_pcreg_layout(tmp_path / "seq", frames_and_masks(6))
    assert damage_notes(load_dataset(f"davis:{seq}")) == []
    for sub, suffix in (("images", "jpg"), ("labels", "png")):
        (seq / sub / f"00003.{suffix}").unlink()
    data = load_dataset(f"davis:{seq}")
    assert [f.name for f in data["seq"]] == ["00000", "00001", "00002", "00004", "00005"]
    assert damage_notes(data) == ["clip seq, frame 00004: 1 frame(s) missing from the numbering before it (00002, then "
                                  "00004), frame and mask (a copy cut short?): DAVIS numbers every frame, so the motion "
                                  "to it spans 2 and the frames scored are not all the benchmark's"]
