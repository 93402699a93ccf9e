"""The legend drawn inside each frame of ``pcreg view RUN --overlay OUT.mp4`` (:mod:`pcreg.legend`).

A real ``pcreg run`` of synthetic frames with a class table of three classes, one of which no frame shows, with
--confidence: the video keeps the frames' size; each frame's legend lists exactly the classes its labels show,
each in its table colour, and the hatching where a label is unsure; outside the legend's box the frame is the
overlay as the review page draws it. A frame too small for its classes shows its name alone, said once.
"""

from __future__ import annotations

import contextlib
import io

import cv2
import numpy as np
import pytest

import pcreg
from pcreg.cli import main
from _view import pcreg_view

N = 4
#: floor and wall are the synthetic frames' ground and obstacle; no frame shows sky.
LABELMAP = "background:0,0,0::\nfloor:0,0,255::\nwall:255,255,0::\nsky:255,0,255::\n"
SKY = (255, 0, 255)


def _run(root, width, height):
    """``pcreg run`` of N synthetic frames of ``width`` x ``height`` under LABELMAP, with --confidence."""
    synthetic = pcreg.synthetic("syn1a", N, 0, width=width, height=height)
    (root / "frames").mkdir(parents=True)
    for i, f in enumerate(synthetic):
        cv2.imwrite(str(root / "frames" / f"frame_{i:03d}.png"), f.image[:, :, ::-1])
    (root / "labelmap.txt").write_text(LABELMAP)
    colours = np.array([(0, 0, 255), (255, 255, 0), (0, 0, 0)], np.uint8)
    cv2.imwrite(str(root / "key.png"), colours[synthetic[0].labels][:, :, ::-1])
    out = root / "out"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["run", str(root / "frames"), "--labels", str(root / "key.png"), "--out", str(out),
                     "--classes", str(root / "labelmap.txt"), "--confidence"]) == 0
    return out


@pytest.fixture(scope="module")
def run_out(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("legend"), 320, 240)


def _colour(table, k):
    return next(c.colour for c in table.known if c.id == k)


def _decoded(video):
    """Every frame of ``video``, decoded with PyAV, RGB."""
    import av

    with av.open(str(video)) as container:
        return [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]


def _inside(box, margin=0):
    x0, y0, x1, y1 = box
    return np.s_[y0 + margin:y1 - margin, x0 + margin:x1 - margin]


def _outside(shape, box):
    mask = np.ones(shape[:2], bool)
    mask[_inside(box)] = False
    return mask


def test_each_frames_legend_lists_its_classes_and_leaves_the_rest_of_the_overlay(run_out):
    from pcreg.export import read_labels
    from pcreg.review import FrameImages, read_overlay, read_review, video_frame

    review = read_review(run_out)
    floor, wall = (c.id for c in review.table.known[:2])
    hatched = []
    with FrameImages(review) as images:
        for t in range(N):
            image = images[t]
            drawn = read_overlay(review, t, image)
            framed, legend = video_frame(review, t, image)
            assert framed.shape == image.shape and legend.complete
            outside = _outside(image.shape, legend.box)
            assert (framed[outside] == drawn[outside]).all()  # the overlay itself, unchanged
            assert np.abs(framed[_inside(legend.box)].astype(int) - drawn[_inside(legend.box)]).mean() > 20
            labels = read_labels(review.labels_path(t), review.table)
            shown = [k for k in (floor, wall) if (labels == k).any()]
            assert shown and [k for k, _ in legend.swatches] == shown, t  # sky, in no frame, is never listed
            for k, box in legend.swatches:
                assert (framed[_inside(box)] == _colour(review.table, k)).all(), (t, k)  # its exact colour
            hatched.append(legend.hatch is not None)
    assert hatched[0] is False  # the key frame: no confidence, nothing hatched
    assert any(hatched[1:])  # a frame pcreg labelled with unsure pixels says what the hatching means


def test_the_video_holds_each_frames_legend_at_the_frames_size(run_out, tmp_path, capsys):
    from pcreg.review import FrameImages, read_overlay, read_review, video_frame

    video = tmp_path / "o.mp4"
    assert pcreg_view([str(run_out), "--overlay", str(video)]) == 0
    assert "too small" not in capsys.readouterr().err
    frames = _decoded(video)
    assert len(frames) == N and all(f.shape == (240, 320, 3) for f in frames)
    review = read_review(run_out)
    with FrameImages(review) as images:
        for t in range(N):
            got = frames[t].astype(int)
            drawn = read_overlay(review, t, images[t]).astype(int)
            framed, legend = video_frame(review, t, images[t])
            outside = _outside(got.shape, legend.box)
            # the frame pcreg draws, up to the video's compression (about 5 on these textured frames); the
            # overlay without its legend, so outside the legend's box alone
            assert np.abs(got - framed).mean() < 8 and np.abs(got[outside] - drawn[outside]).mean() < 8
            assert np.abs(got[~outside] - drawn[~outside]).mean() > 40
            for k, box in legend.swatches:  # each class present, in its colour
                assert np.abs(got[_inside(box, 2)] - _colour(review.table, k)).mean() < 12, (t, k)
            near_sky = np.abs(got[_inside(legend.box)] - SKY).max(axis=-1) < 40
            assert not near_sky.any()  # the class no frame shows is not in the legend


def test_a_frame_too_small_for_its_legend_shows_its_name_alone(tmp_path, capsys):
    from pcreg.classes import CAMVID11
    from pcreg.legend import draw_legend

    image = np.full((120, 160, 3), 90, np.uint8)
    labels = np.repeat((np.arange(160) * 11 // 160).astype(np.uint8)[None], 120, axis=0)  # all eleven classes
    drawn, legend = draw_legend(image, labels, title="0001TP_006690.png", table=CAMVID11, hatched_below=0.7)
    assert not legend.complete and legend.swatches == () and legend.hatch is None
    assert (drawn[_outside(image.shape, legend.box)] == 90).all()
    x0, y0, x1, y1 = legend.box
    assert y1 - y0 < 20 and (drawn[y0:y1, x0:x1] > 200).any()  # one row: the name, in white
    # at 320x240 the same eleven classes fit
    big = draw_legend(cv2.resize(image, (320, 240)), cv2.resize(labels, (320, 240), interpolation=cv2.INTER_NEAREST),
                      title="0001TP_006690.png", table=CAMVID11, hatched_below=0.7)[1]
    assert big.complete and [k for k, _ in big.swatches] == list(range(11)) and big.hatch is not None
    # the command says it once on stderr, and writes every frame
    out = _run(tmp_path, 96, 72)
    video = tmp_path / "small.mp4"
    assert pcreg_view([str(out), "--overlay", str(video)]) == 0
    err = capsys.readouterr().err
    assert err.count("too small for the legend") == 1 and str(video) in err
    frames = _decoded(video)
    assert len(frames) == N and all(f.shape == (72, 96, 3) for f in frames)


def test_a_labelled_frames_legend_gives_its_predicted_error_and_each_classs_predicted_iou(run_out):
    import json

    from pcreg.review import FrameImages, frame_figures, read_review, video_frame

    review = read_review(run_out)
    steps = [json.loads(line) for line in (run_out / "steps.jsonl").read_text().splitlines()]
    assert frame_figures(review, 0) == {}  # the key frame: nothing predicted
    with FrameImages(review) as images:
        assert not video_frame(review, 0, images[0])[1].figures
        for t in range(1, N):
            step = steps[t - 1]
            got = frame_figures(review, t)
            assert got["figures"] == f"predicted error {step['predicted_error']:.1f}%"  # in % there
            assert got["scores"] == {int(k): f"{v:.2f}" for k, v in step["predicted_iou"].items()}
            assert got["scores_key"] == "after each class its predicted IoU"
            legend = video_frame(review, t, images[t])[1]
            assert legend.complete and legend.figures and legend.scored, t  # two classes fit at 320x240
            assert [k for k, _ in legend.swatches] == sorted(got["scores"])


def test_what_does_not_fit_goes_first_the_scores_then_the_figures_then_the_classes():
    from pcreg.classes import CAMVID11
    from pcreg.legend import draw_legend

    labels = np.repeat((np.arange(640) * 11 // 640).astype(np.uint8)[None], 480, axis=0)  # all eleven classes
    figures = "predicted error 12.3% (truth 10.1%)"
    scores = {k: "0.55 (0.61)" for k in range(11)}
    key = "after each class its IoU, predicted (truth)"
    legends = {}
    for w, h in ((960, 720), (640, 480), (320, 240), (160, 120)):
        image = np.full((h, w, 3), 90, np.uint8)
        lab = cv2.resize(labels, (w, h), interpolation=cv2.INTER_NEAREST)
        drawn, legend = draw_legend(image, lab, title="0001TP_006690.png", table=CAMVID11, figures=figures,
                                    scores=scores, scores_key=key)
        assert (drawn[_outside(image.shape, legend.box)] == 90).all()
        legends[w] = legend
        # with nothing to score the same frame's legend is that of before, figures or not
        bare = draw_legend(image, lab, title="0001TP_006690.png", table=CAMVID11)[1]
        assert not bare.figures and not bare.scored and bare.complete == (w >= 320)
    assert [(g.complete, g.figures, g.scored) for g in legends.values()] == [
        (True, True, True), (True, True, True), (True, True, False), (False, False, False)]
    assert [k for k, _ in legends[960].swatches] == list(range(11)) == [k for k, _ in legends[320].swatches]


def test_a_frames_figures_read_predicted_then_against_the_truth_in_brackets():
    from pcreg.legend import legend_figures

    assert legend_figures(None, {1: 0.5}, 3.0, {1: 0.4}) == {}  # a key frame
    assert legend_figures(5.66, None) == {"figures": "predicted error 5.7%"}  # a step of an earlier pcreg
    assert legend_figures(5.66, {0: 0.981, 8: 0.7749}) == {
        "figures": "predicted error 5.7%", "scores": {0: "0.98", 8: "0.77"},
        "scores_key": "after each class its predicted IoU"}
    # the truth's IoU where it has the class (it names every class its truth or the labels hold)
    assert legend_figures(5.66, {0: 0.981, 8: 0.7749}, 2.94, {0: 0.99, 3: 0.2, 8: 0.0}) == {
        "figures": "predicted error 5.7% (truth 2.9%)", "scores": {0: "0.98 (0.99)", 8: "0.77 (0.00)"},
        "scores_key": "after each class its IoU, predicted (truth)"}
    # a truth that holds no known class (void all over): no class's IoU against it, the key says predicted alone
    assert legend_figures(5.66, {0: 0.981}, None, {}) == {
        "figures": "predicted error 5.7%", "scores": {0: "0.98"},
        "scores_key": "after each class its predicted IoU"}


def test_class_names_of_no_ascii_form_are_drawn_apart():
    """The legend's font is ASCII: 道路, 天空 and 其他 were each drawn as "??", three classes alike. Accents are folded,
    a name of no ASCII form is drawn as its id, and names that still read alike gain their ids."""
    from pcreg.classes import LabelClass
    from pcreg.legend import drawn_names

    classes = [LabelClass(1, "道路", (1, 1, 1)), LabelClass(2, "天空", (2, 2, 2)), LabelClass(3, "nébo", (3, 3, 3)),
               LabelClass(5, "road", (5, 5, 5)), LabelClass(6, "rôad", (6, 6, 6)), LabelClass(7, "sky", (7, 7, 7))]
    assert drawn_names(classes) == {1: "class 1", 2: "class 2", 3: "nebo", 5: "road (5)", 6: "road (6)", 7: "sky"}
    letters = [LabelClass(1, "Straße", (1, 1, 1)), LabelClass(2, "Łąka", (2, 2, 2)), LabelClass(3, "æble", (3, 3, 3))]
    assert drawn_names(letters) == {1: "Strasse", 2: "Laka", 3: "aeble"}  # letters of no accent are not dropped
    # accents as separate marks (decomposed, as some systems write file names) are folded as composed ones, not "?"
    marks = [LabelClass(1, "cafe\u0301", (1, 1, 1)), LabelClass(2, "q\u0303uay", (2, 2, 2)), LabelClass(3, "cafe", (3, 3, 3))]
    assert drawn_names(marks) == {1: "cafe (1)", 2: "quay", 3: "cafe (3)"}
