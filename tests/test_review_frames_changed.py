"""``pcreg view RUN`` of a run whose frames folder changed since (a frame added among the labelled ones, or one
renamed): the review placed its frames by their position in the folder as it is now, found a frame the run never
labelled there and said ``steps.jsonl: missing or unreadable (3 steps for 4 labelled frames; none for f2b.png)``,
blaming a file that is whole. It names the folder and the frame that moved, as resuming the run does."""

from __future__ import annotations

import contextlib
import io

import cv2
import pytest

import pcreg
from pcreg.cli import main
from pcreg.errors import InputError
from pcreg.review import read_review


@pytest.fixture(scope="module")
def synthetic():
    return pcreg.synthetic("syn1a", 6, 0, width=96, height=72)


def _run(tmp_path, synthetic, keys: bool):
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, f in enumerate(synthetic[:5]):
        cv2.imwrite(str(folder / f"f{i}.png"), f.image[:, :, ::-1])
    (tmp_path / "keys").mkdir()
    for k in (0, 4) if keys else (0,):
        cv2.imwrite(str(tmp_path / "keys" / f"f{k}.png"), synthetic[k].labels)
    labels = tmp_path / "keys" if keys else tmp_path / "keys" / "f0.png"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(folder), "--labels", str(labels), "--out", str(tmp_path / "out")]) == 0
    return folder, tmp_path / "out"


@pytest.mark.parametrize("keys", [False, True], ids=["one label image", "a folder of key frames"])
@pytest.mark.parametrize("change", ["added", "renamed"])
def test_a_frame_added_or_renamed_since_the_run_is_named(synthetic, tmp_path, keys, change):
    folder, out = _run(tmp_path, synthetic, keys)
    if change == "added":
        cv2.imwrite(str(folder / "f2b.png"), synthetic[5].image[:, :, ::-1])
        now = "f2b.png"
    else:
        (folder / "f3.png").rename(folder / "f3x.png")
        now = "f3x.png"
    with pytest.raises(InputError) as caught:
        read_review(out)
    assert str(caught.value) == (f"{folder}: holds {now} as frame 3, which the run in {out} labelled as f3.png: the "
                                 "frames changed since the run (a frame added, removed or renamed)")



def test_a_frame_written_again_since_the_run_is_named_not_drawn_under_old_labels(synthetic, tmp_path):
    """A frame replaced by another picture of its size (re-extracted, edited): `pcreg view --overlay` drew the run's
    labels over the new picture, exit 0, where resuming the run refuses it. Refused naming the frame."""
    folder, out = _run(tmp_path, synthetic, False)
    f2 = folder / "f2.png"
    cv2.imwrite(str(f2), 255 - cv2.imread(str(f2)))
    with pytest.raises(InputError, match=r"f2\.png: changed since the run in .* labelled it .*label it again"):
        read_review(out)
    assert main(["view", str(out), "--overlay", str(tmp_path / "o.mp4")]) == 2
    assert not (tmp_path / "o.mp4").exists()


@pytest.mark.parametrize("keys", [False, True], ids=["one label image", "a folder of key frames"])
@pytest.mark.parametrize("change", ["smaller", "renamed", "gone"])
def test_export_refuses_frames_changed_since_as_the_review_does(tmp_path, synthetic, capsys, keys, change):
    """Frames re-extracted at another size since the run: the review refused them, the export wrote the labels of the
    frames as they were (exit 0, masks of 96x72 for frames of 48x36) and told to make a CVAT task "over the same
    frames". Refused the same way; a frames folder that is gone (the labels are all an export needs) is exported."""
    import shutil

    folder, out = _run(tmp_path, synthetic, keys)
    if change == "smaller":
        f2 = cv2.imread(str(folder / "f2.png"))
        cv2.imwrite(str(folder / "f2.png"), cv2.resize(f2, (48, 36)))
    elif change == "renamed":
        (folder / "f2.png").rename(folder / "f2b.png")
    else:
        shutil.rmtree(folder)
    capsys.readouterr()
    code = main(["export", str(out), "--to", str(tmp_path / "a.zip")])
    err = capsys.readouterr().err.strip().splitlines()
    if change == "gone":
        assert code == 0 and (tmp_path / "a.zip").is_file(), err
        return
    assert code == 2 and len(err) == 1 and not (tmp_path / "a.zip").exists(), err
    said = (f"{folder / 'f2.png'}: changed since the run in {out} labelled it" if change == "smaller" else
            f"{folder}: holds f2b.png as frame 2, which the run in {out} labelled as f2.png")
    assert said in err[0] and ("to export it" in err[0] or change != "smaller"), err


@pytest.mark.parametrize("then", ["appended", "written over"])
def test_a_video_written_over_since_the_run_is_refused_by_the_review_and_the_export(tmp_path, capsys, then):
    """A run's video replaced by another of its size and length (the clip reversed): `pcreg run` refused to resume on it,
    while `pcreg view` served its frames under the old labels and `pcreg export` wrote them for the new frames, exit 0,
    without a word. Bytes appended (a recording still growing) are the same video: both go on."""
    from _runs import video_run, write_video

    video, out = video_run(tmp_path, frames=4)
    if then == "appended":
        with open(video, "ab") as fh:
            fh.write(b"\0" * 64)
    else:
        write_video(video, pcreg.synthetic("syn1a", 4, 0, width=96, height=72)[::-1])
    capsys.readouterr()
    codes = [main(["view", str(out), "--overlay", str(tmp_path / "o.mp4")]),
             main(["export", str(out), "--to", str(tmp_path / "x.zip")])]
    err = capsys.readouterr().err
    if then == "appended":
        assert codes == [0, 0], err
        return
    assert codes == [2, 2] and not (tmp_path / "o.mp4").exists() and not (tmp_path / "x.zip").exists()
    said = f"{video}: not the video the run in {out} labelled (its size or bytes changed since"
    assert [line.startswith(f"pcreg: error: {said}") for line in err.splitlines() if "error" in line] == [True, True], err
    with pytest.raises(InputError, match="label it again .* to review it"):
        read_review(out)
