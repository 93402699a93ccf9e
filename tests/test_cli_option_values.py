"""Option values a careless or hostile user types: refused by the parser in one line naming the option, exit 2,
before anything is read or run."""

from __future__ import annotations

import contextlib
import io

import cv2
import numpy as np
import pytest

from pcreg.cli import main
from pcreg.errors import InputError


@pytest.mark.parametrize("argv, option", [
    (["register", "a.png", "b.png", "--levels", "100"], "--levels"),
    (["register", "a.png", "b.png", "--max-distance", "1e7"], "--max-distance"),
    (["view", "run", "--overlay", "o.mp4", "--fps", "0.0004"], "--fps"),
    # an empty path is the current folder: --out '' wrote a run's or the demo's files there
    (["run", "frames", "--labels", "key.png", "--out", ""], "--out"),
    (["run", "", "--labels", "key.png", "--out", "o"], "FRAMES"),
    (["demo", "--out", ""], "--out"),
    (["evaluate", "stream", "--out", ""], "--out"),
    (["export", ""], "OUT"),
    # and an empty option was taken for one not given: --init '' ran from the identity
    (["crosscheck", "a.npy", "b.npy", "--init", ""], "--init"),
    (["crosscheck", "a.npy", "b.npy", "--record", ""], "--record"),
])
def test_an_option_value_that_cannot_be_meant_is_refused_naming_the_option(tmp_path, monkeypatch, capsys, argv, option):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"argument {option}" in err[0]


def test_an_overlay_rate_the_video_cannot_store_is_refused_not_replaced_by_24_fps(tmp_path):
    """A rate below 1/1000 was stored as 0, which the muxer replaced by 24 fps: a video of the wrong speed."""
    import av

    from pcreg.review import read_review, write_overlay_video

    frames = tmp_path / "frames"
    frames.mkdir()
    base = cv2.GaussianBlur((np.random.default_rng(0).random((48, 64, 3)) * 255).astype(np.uint8), (5, 5), 0)
    for i in range(3):
        cv2.imwrite(str(frames / f"{i:03d}.png"), np.roll(base, i, axis=1))
    labels = np.zeros((48, 64), np.uint8)
    labels[24:] = 1
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(frames), "--labels", str(tmp_path / "key.png"), "--out", str(tmp_path / "out")]) == 0
    review = read_review(tmp_path / "out")
    with pytest.raises(InputError, match="fps must be >= 0.001"):
        write_overlay_video(review, tmp_path / "slow.mp4", fps=0.0004)
    assert not (tmp_path / "slow.mp4").exists()
    write_overlay_video(review, tmp_path / "o.mp4", fps=0.001)
    with av.open(str(tmp_path / "o.mp4")) as container:
        assert str(container.streams.video[0].average_rate) == "1/1000"


@pytest.mark.parametrize("extra", [[], ["--max-distance", "1"]])
def test_a_voxel_size_that_merges_a_cloud_into_too_few_points_names_the_voxel_size(tmp_path, capsys, extra):
    """It said "a.npy: a single point", of a file of 200 points, or failed inside the implementations."""
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    cloud = np.random.default_rng(0).random((200, 3))
    np.save(a, cloud)
    np.save(b, cloud + 0.01)
    assert main(["crosscheck", str(a), str(b), "--voxel-size", "1e308", *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "(--voxel-size) merges its 200 points into 1, and the ICP needs 3" in err[0]


@pytest.mark.parametrize("value, angles", [("-30,0,30", (-30.0, 0.0, 30.0)), ("-90:90:45", (-90.0, -45.0, 0.0, 45.0, 90.0)),
                                           ("-.5,0.5", (-0.5, 0.5))])
def test_a_value_that_begins_with_a_minus_and_a_digit_is_the_option_s_value(value, angles):
    # argparse took "-30,0,30" for an option: "argument --angles: expected one argument"
    from pcreg.cli import build_parser

    args = build_parser().parse_args(["evaluate", "rotation", "--angles", value])
    assert tuple(args.angles) == angles


def test_an_option_that_pcreg_has_not_is_still_refused(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", "rotation", "-x", "--angles", "0,5"])
    assert exc.value.code == 2 and "unrecognized arguments: -x" in capsys.readouterr().err
