"""DAVIS's splits (pcreg.datasets.davis_splits): an official download is evaluated on the split its ImageSets
name, DAVIS 2016 val by default, in either format the downloads ship; another split or all of them on
request; published means over the sequences that have figures; bad split files are exit 2 naming them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pcreg.cli import main
from pcreg.datasets import data_folder, load_dataset
from pcreg.datasets.davis import published, select_sequences
from pcreg.datasets.davis_splits import parse_davis_arg, read_split_file
from pcreg.errors import DatasetError, InputError
from _davis import frames_and_masks, write_official_layout, write_pcreg_layout
from _runs import one_line_errors

#: DAVIS 2016's split of the sequences the tests write: val (published figures ship for them) and train.
VAL, TRAIN = ("blackswan", "camel"), ("bear",)


def _frame_lines(names, n: int = 3) -> str:
    """DAVIS 2016's ImageSets/480p format: one line a frame, image and mask paths from ROOT."""
    return "".join(f"/JPEGImages/480p/{s}/{i:05d}.jpg /Annotations/480p/{s}/{i:05d}.png\n" for s in names
                   for i in range(n))


def _official(tmp_path, *, year: int | None = 2016):
    """A tiny official root: three sequences of 3 frames of 64x48, with the ImageSets of DAVIS ``year``'s
    download (2016: frame lines under ImageSets/480p; 2017: names under ImageSets/2016 and 2017; None: none)."""
    root = tmp_path / "DAVIS"
    for i, name in enumerate(sorted(VAL + TRAIN)):
        write_official_layout(root, name, frames_and_masks(3, seed=i))
    if year == 2016:
        (root / "ImageSets" / "480p").mkdir(parents=True)
        (root / "ImageSets" / "480p" / "val.txt").write_text(_frame_lines(VAL))
        (root / "ImageSets" / "480p" / "train.txt").write_text(_frame_lines(TRAIN))
    elif year == 2017:
        for sub, val, train in (("2016", VAL, TRAIN), ("2017", ("bear",), VAL)):  # 2017's split is another
            (root / "ImageSets" / sub).mkdir(parents=True)
            (root / "ImageSets" / sub / "val.txt").write_text("\n".join(val) + "\n")
            (root / "ImageSets" / sub / "train.txt").write_text("\n".join(train) + "\n")
    return root


@pytest.mark.parametrize("year", [2016, 2017])
def test_an_official_root_reads_davis_2016_val_by_default_and_another_split_on_request(tmp_path, year):
    root = _official(tmp_path, year=year)
    for where in (root, root / "JPEGImages" / "480p"):
        assert list(load_dataset(f"davis:{where}")) == list(VAL)
        assert list(load_dataset(f"davis:{where}:train")) == list(TRAIN)
        assert list(load_dataset(f"davis:{where}:all")) == sorted(VAL + TRAIN)
    chosen = select_sequences(root)[2]
    listed = "ImageSets/480p/val.txt" if year == 2016 else "ImageSets/2016/val.txt"
    assert chosen.file == listed and chosen.describe() == f"DAVIS 2016 val ({listed}): 2 of 3 sequences"
    assert select_sequences(root, split="all")[2].describe() == "all 3 sequences (:all asked for)"
    assert data_folder(f"davis:{root}:train") == root  # --out beside the data is still checked


def test_without_imagesets_or_in_pcregs_layout_every_sequence_is_read(tmp_path):
    root = _official(tmp_path, year=None)
    assert list(load_dataset(f"davis:{root}")) == sorted(VAL + TRAIN)
    assert select_sequences(root)[2].describe() == f"all 3 sequences (no ImageSets/480p/val.txt or " \
        f"ImageSets/2016/val.txt in {root})"
    ours = write_pcreg_layout(tmp_path / "ours" / "disc", frames_and_masks(3)).parent
    assert list(load_dataset(f"davis:{ours}")) == ["disc"] and select_sequences(ours)[2].describe() == "its one sequence"
    with pytest.raises(DatasetError, match="no val.txt under 480p/ or 2016/ "):
        load_dataset(f"davis:{root}:val")
    with pytest.raises(DatasetError, match="no DAVIS split here"):
        load_dataset(f"davis:{ours}:train")


def test_split_files_of_both_formats_parse_and_a_path_with_a_colon_is_a_path(tmp_path):
    f = tmp_path / "val.txt"
    f.write_text(_frame_lines(("camel", "blackswan")) + "\n")
    assert read_split_file(f) == ["camel", "blackswan"]
    f.write_text("camel\n  blackswan \n\ncamel\n")
    assert read_split_file(f) == ["camel", "blackswan"]
    odd = tmp_path / "a:train"
    odd.mkdir()
    assert parse_davis_arg(str(odd)) == (str(odd), None)
    assert parse_davis_arg(f"{tmp_path}/DAVIS:all") == (f"{tmp_path}/DAVIS", "all")
    with pytest.raises(InputError, match="'test' is no split"):
        parse_davis_arg(f"{tmp_path}/DAVIS:test")


def test_a_byte_order_mark_is_no_part_of_a_split_file_or_of_published_figures(tmp_path):
    # saved by Notepad or as Excel's "CSV UTF-8": the mark began the first name, "\ufeffcamel" (no folder), and
    # the first column, "\ufeffmethod" (the published results "need the columns ... method")
    f = tmp_path / "val.txt"
    f.write_text("\ufeffcamel\r\nblackswan\r\n", encoding="utf-8")
    assert read_split_file(f) == ["camel", "blackswan"]
    seq = write_pcreg_layout(tmp_path / "mine" / "camel", frames_and_masks(3))
    (seq.parent / "published_mine.csv").write_text("\ufeffmethod,sequence,J_mean,F_mean\r\nmine,camel,0.5,0.4\r\n",
                                                   encoding="utf-8")
    doc = published(seq.parent)
    assert doc["methods"] == ["mine"] and doc["J"]["mine"] == {"camel": 0.5} and doc["F"]["mine"] == {"camel": 0.4}


def _stream(tmp_path, spec: str, out_name: str, capsys) -> tuple[dict, str]:
    out = tmp_path / out_name
    assert main(["evaluate", "stream", "--data", spec, "--methods", "unregistered", "--out", str(out)]) == 0
    return json.loads((out / "results.json").read_text())["davis"], capsys.readouterr().out


def test_evaluate_stream_says_which_split_and_averages_the_published_figures_it_has(tmp_path, capsys):
    root = _official(tmp_path)
    pub = published(root)
    d, printed = _stream(tmp_path, f"davis:{root}", "val", capsys)
    assert "DAVIS: DAVIS 2016 val (ImageSets/480p/val.txt): 2 of 3 sequences" in printed
    assert "DAVIS sequences evaluated: DAVIS 2016 val (ImageSets/480p/val.txt): 2 of 3 sequences" in printed
    assert list(d["sequences"]) == list(VAL) and d["split"]["name"] == "val"
    assert d["published"]["mean"]["J"]["osvos"] == pytest.approx(np.mean([pub["J"]["osvos"][s] for s in VAL]))
    assert d["published"]["counted"]["J"]["osvos"] == 2 and "mean_covered" not in d
    # every sequence: bear has no published figure; the published means are over the two that have one
    d, printed = _stream(tmp_path, f"davis:{root}:all", "all", capsys)
    assert "DAVIS: all 3 sequences (:all asked for)" in printed and list(d["sequences"]) == sorted(VAL + TRAIN)
    for k in ("J", "F"):
        for p in d["published"]["methods"]:
            assert d["published"][k][p]["bear"] is None  # NaN, written as null
            assert d["published"]["mean"][k][p] == pytest.approx(np.mean([pub[k][p][s] for s in VAL]))
            assert d["published"]["counted"][k][p] == 2
            assert d["mean_covered"][k][p] == pytest.approx(d["published"]["mean"][k][p])
        assert d["mean_covered"][k]["plain"] == pytest.approx(np.mean([d["sequences"][s][k]["plain"] for s in VAL]))
    assert d["published"]["covered"] == list(VAL)
    table = (tmp_path / "all" / "davis_J.md").read_text()
    assert "| mean over the 2 with published figures | 2 |" in table
    assert "The published means are over the sequences with a figure only (OSVOS 2, " in table
    assert "Sequences: all 3 sequences (:all asked for)." in table


@pytest.mark.parametrize("how", ["a sequence without folder", "a line that does not parse", "an unknown split",
                                 "a split without its file", "a folder named as the split", "a link to nothing"])
def test_a_bad_split_is_one_line_and_exit_2_naming_it(tmp_path, capsys, how):
    root = _official(tmp_path)
    val = root / "ImageSets" / "480p" / "val.txt"
    spec, named = f"davis:{root}", [str(val)]
    if how == "a sequence without folder":
        val.write_text(_frame_lines(VAL + ("goat",)))
        named += ["'goat'", "no folder"]
    elif how == "a line that does not parse":
        val.write_text(_frame_lines(VAL) + "/JPEGImages/480p/camel/00000.jpg /Annotations/x.png extra\n")
        named += ["line 7"]
    elif how == "an unknown split":
        spec, named = f"davis:{root}:test-dev", ["'test-dev' is no split", str(root)]
    elif how == "a split without its file":
        (root / "ImageSets" / "480p" / "train.txt").unlink()
        spec, named = f"davis:{root}:train", [str(root / "ImageSets"), "no train.txt"]
    else:  # read as absent, every sequence was evaluated in the split's place
        val.unlink()
        val.mkdir() if how == "a folder named as the split" else val.symlink_to(tmp_path / "gone.txt")
        named += ["cannot read the split file", "Is a directory" if how == "a folder named as the split" else "No such file"]
    out = tmp_path / "out"
    out.mkdir()
    (out / "results.json").write_text("{}")  # an earlier evaluation's
    assert main(["evaluate", "stream", "--data", spec, "--methods", "unregistered", "--out", str(out)]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and all(n in err[0] for n in named), err
    assert (out / "results.json").read_text() == "{}"


def test_frames_of_another_resolution_than_the_published_figures_are_said(tmp_path):
    """An official root with Full-Resolution/ only was evaluated beside the published figures (of 480p frames)
    with nothing saying the frames were another resolution's."""
    pairs = frames_and_masks(3)
    full = write_official_layout(tmp_path / "full", "seq", pairs, resolution="Full-Resolution")
    small = write_official_layout(tmp_path / "small", "seq", pairs)
    for where in (full, full / "JPEGImages" / "Full-Resolution", full / "JPEGImages" / "Full-Resolution" / "seq"):
        chosen = select_sequences(where)[2]
        assert chosen.resolution == "Full-Resolution"
        assert chosen.describe().endswith("; frames of Full-Resolution/, where the published figures are of 480p/")
    assert "published" not in select_sequences(small)[2].describe()
    assert select_sequences(small)[2].to_dict()["resolution"] == "480p"
