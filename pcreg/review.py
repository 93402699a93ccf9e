"""A ``pcreg run`` output as a person reviews it: each frame with its labels drawn over it.

:func:`read_review` reads what a run's folder says about its frames (``run.json``, ``steps.jsonl``, and
``suggest.txt`` when there is one): the frames in order, which are key frames, each frame's predicted
error and the frames suggested to label next. :class:`FrameImages` reads the frames themselves from the
run's source, a folder of images or a video. :func:`overlay` draws one frame's labels over it (each
class in its colour of the run's class table, :mod:`pcreg.classes`; unknown left clear) and, with its confidence, hatches the pixels whose label is
less sure than :data:`LOW_CONFIDENCE`. :func:`write_overlay_video` writes every frame so drawn as a video, of the
frames' size, each with a legend drawn in (:func:`video_frame`, :mod:`pcreg.legend`): its name, its figures, its
classes, the hatching.

A video is read in decoding order, never by seeking (as :mod:`pcreg.datasets.sources` reads it), so
that frame ``i`` is the run's frame ``i``. For a page that jumps about a long video,
:class:`FrameImages` decodes it in a thread into JPEG files in ``OUT/.pcreg-review/``: a frame is shown
as soon as the decoding reaches it (a frame far ahead is skipped to, decoding without converting the
frames between), and at once the next time the run is reviewed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from .classes import DEFAULT_TABLE, ClassTable
from .errors import InputError
from .validation import check_float
from .formats import loads_json
from ._moved import moved
from .runs.files import StepTruth, finite_figure, step_class_iou
from .legend import Legend, draw_legend, legend_figures
from .review_frames import FrameImages

__all__ = ["LOW_CONFIDENCE", "COLOURS", "ALPHA", "CACHE", "RunReview", "read_review", "overlay", "FrameImages", "video_frame", "write_overlay_video"]

#: A label is marked unsure where its confidence (the probability that it is right) is below this.
LOW_CONFIDENCE = 0.7
#: Class id -> RGB drawn over the frame for the default table (``lagr``); unknown (2) is left clear.
COLOURS: dict[int, tuple[int, int, int]] = {0: (34, 197, 94), 1: (255, 40, 40)}
#: How much of a labelled pixel is the label's colour (the rest is the frame).
ALPHA = 0.5
#: The hidden folder in a run's output where the review keeps what it decoded.
CACHE = ".pcreg-review"


@dataclass(frozen=True)
class RunReview:
    """What a run's folder says about its frames, in run order (position 0 is the first chosen frame).

    ``names`` are the frames' names (a folder's file names, ``{i:06d}`` in a video), ``stems`` what
    their outputs are named after (``OUT/STEM.png``, ``OUT/confidence/STEM.png``); ``keys`` the positions
    of key frames (named in ``run.json``; with its ``key_frames`` list, also those without a line in
    ``steps.jsonl``); ``errors`` each frame's
    predicted error in % (None for a key frame or a step without one); ``suggested`` the positions listed in
    ``suggest.txt`` with the error given there (or None); ``confidence`` whether the run was asked for its confidence
    (run.json) or ``OUT/confidence/`` exists (its frames without their map each marked, the folder removed too);
    ``table`` the run's class table (:func:`pcreg.classes.keys.run_table`); ``ious`` each frame's predicted
    IoU per class id (``steps.jsonl``'s ``predicted_iou``; None where a step has none: a key frame, a two-class
    step of an earlier pcreg); ``truths`` each frame's figures against the truth (a run with ``--truth``: a
    :class:`~pcreg.runs.files.StepTruth`; None for a key frame); ``gaps``
    run.json's places where the video skips frames by its times (:mod:`pcreg.runs.gaps`; None without one),
    ``damaged`` its frames that decode with errors (the same module's; None without one), ``notes`` what else reading
    its frames met (run.json's ``notes``: transparent pixels, a turn to interlaced; None without one)."""

    folder: Path
    source: Path
    kind: str  # "folder" or "video"
    names: tuple[str, ...]
    stems: tuple[str, ...]
    keys: frozenset[int]
    errors: tuple[float | None, ...]
    suggested: tuple[tuple[int, float | None], ...]
    confidence: bool
    selection: dict | None = None
    table: ClassTable = DEFAULT_TABLE
    ious: tuple[dict | None, ...] = ()
    truths: tuple[StepTruth | None, ...] = ()
    chosen: int | None = None  # the frames the run chose of its folder (None: a video)
    gaps: dict | None = None
    damaged: dict | None = None
    notes: dict | None = None

    def said(self) -> tuple[str, ...]:
        """Every line the review says of the run's frames, in order: where its video skips frames, its frames that
        decode with errors (:meth:`gaps_note`, :meth:`damaged_note`) and what else reading them met
        (:meth:`kept_notes`); none for a run that met nothing."""
        return tuple(filter(None, (self.gaps_note(), self.damaged_note(), *self.kept_notes())))

    def kept_notes(self) -> tuple[str, ...]:
        """What the review says again of what reading the run's frames met (:func:`pcreg.runs.gaps.kept_notes`)."""
        from .runs.gaps import kept_notes

        return kept_notes(self.notes)

    def damaged_note(self) -> str | None:
        """What the review says of the run's video's frames that decode with errors (:func:`pcreg.runs.gaps.damaged_note`)."""
        from .runs.gaps import damaged_note

        return damaged_note(self.damaged, self.source)

    def gaps_note(self) -> str | None:
        """What the review says of the places the run's video skips frames (:func:`pcreg.runs.gaps.gaps_note`)."""
        from .runs.gaps import gaps_note

        return gaps_note(self.gaps, self.source)

    def labels_path(self, t: int) -> Path:
        return self.folder / f"{self.stems[t]}.png"

    def truth_at(self, t: int) -> StepTruth | None:
        """Frame ``t``'s figures against the truth (:attr:`truths`), None where it has none."""
        return self.truths[t] if t < len(self.truths) else None

    def confidence_path(self, t: int) -> Path | None:
        from .runs.files import CONFIDENCE

        p = self.folder / CONFIDENCE / f"{self.stems[t]}.png"
        return p if self.confidence and t not in self.keys and p.is_file() else None


def is_run(folder: str | Path) -> bool:
    """Whether ``folder`` is a ``pcreg run`` output (it holds a ``run.json`` naming the run's source)."""
    from .runs.state import STATE

    p = Path(folder) / STATE
    if not p.is_file():
        return False
    try:
        state = loads_json(p.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    return isinstance(state, dict) and isinstance(state.get("run"), dict) and ("key_frame" in state or "stretches" in state
                                                                         or "format" in state)


def read_review(folder: str | Path) -> RunReview:
    """The frames of the ``pcreg run`` output in ``folder``, those counted done in its ``run.json``.

    Raises :class:`~pcreg.errors.InputError` naming the file: no ``run.json``, one pcreg run did not write,
    a source that is gone, an unreadable ``steps.jsonl`` or ``suggest.txt``.
    """
    from .classes.keys import run_table
    from .datasets.sources import FolderFrames, open_frames
    from .runs.edited import FramesAsLabelled, check_source
    from .runs.files import STEPS, counted_steps, has_confidence
    from .runs.state import STATE, chosen_selection, read_state, run_frames, steps_counted_now

    folder = Path(folder)
    state_path = folder / STATE
    state = read_state(folder)
    try:
        run = state["run"]
        kind = "video" if "video" in run else "folder"
        source = Path(run[kind])
        labelled: list[str] | None = None
        if "stretches" in state:  # a run from a folder of key frames: its keys and the steps it counted
            try:
                named, labelled = run_frames(state, folder)
            except (OSError, ValueError) as exc:  # run.json was read: steps.jsonl missing, or fewer steps than it counts
                raise InputError(f"{folder / STEPS}: missing or unreadable ({exc})") from None
            counted = int(state["lines"])
        else:
            named, count = [str(state["key_frame"])], int(state["done"])
            counted = count - 1
        named = [*named, *map(str, state.get("key_frames") or [])]
        selection = chosen_selection(run, state_path)
    except InputError:  # steps.jsonl's or run.json's, named
        raise
    except (OSError, ValueError, KeyError, TypeError, AttributeError, UnicodeDecodeError):
        raise InputError(f"{state_path}: unreadable (not a run.json that pcreg run wrote)") from None
    table = run_table(run, str(state_path))
    check_source(state, kind, source, folder)
    frames = open_frames(source, selection)
    if labelled is None:  # a run from one label image labels its frames in order
        done = min(count, len(frames)) if isinstance(frames, FolderFrames) else count
    else:  # stretch by stretch: the frames labelled from the first on
        done, wanted = 0, set(labelled)
        while done < len(labelled) and (not isinstance(frames, FolderFrames) or done < len(frames)) \
                and frames.name(done) in wanted:
            done += 1
    names = [frames.name(t) for t in range(done)]
    stems = [frames.stem(t) for t in range(done)]
    steps: dict[str, dict] = {}  # of each step what the review shows: an hour's steps whole take about a GB
    steps_path = folder / STEPS
    seen = FramesAsLabelled(frames, folder, "review", str(state["key_frame"]) if labelled is None else None,
                            keys=() if labelled is None else named)
    try:  # the steps run.json counts: a line after them (a run stopped by a full disk) is not read
        for step in counted_steps(folder, counted, recount=lambda: steps_counted_now(folder)):
            steps[str(step["name"])] = {k: step.get(k) for k in ("predicted_error", "predicted_iou", "error", "iou")}
            seen.step(step)  # a frame written again since, or not where the run labelled it (a frames folder changed)
    except InputError:  # a line named
        raise
    except (OSError, ValueError, KeyError, TypeError):
        raise InputError(f"{steps_path}: unreadable (not the steps.jsonl pcreg run wrote)") from None
    seen.check()
    legacy = "key_frames" in state  # a run.json that lists its key frames leaves their steps out
    keys = frozenset(t for t, n in enumerate(names) if n in named or (legacy and n not in steps))
    stepless = [n for t, n in enumerate(names) if t not in keys and n not in steps]
    if stepless:  # as the export refuses it: such a frame would be shown as a key frame
        raise InputError(f"{steps_path}: missing or unreadable ({len(names) - len(keys) - len(stepless)} steps for "
                         f"{len(names) - len(keys)} labelled frames; none for {stepless[0]})")
    errors: list[float | None] = []
    truth: list[StepTruth | None] = []
    ious = []
    for t, n in enumerate(names):
        error, scored = (None, None) if t in keys else (finite_figure(steps[n].get("predicted_error")), finite_figure(steps[n].get("error")))
        errors.append(error)
        ious.append(None if t in keys else step_class_iou(steps[n].get("predicted_iou"), steps_path, n))
        truth.append(None if t in keys else StepTruth(scored, step_class_iou(steps[n].get("iou"), steps_path, n, "iou")))
    return RunReview(folder, source, kind, tuple(names), tuple(stems), keys, tuple(errors),
                     _suggested(folder, names, stems, keys), has_confidence(folder, run), selection.to_dict(), table,
                     tuple(ious), tuple(truth), len(frames) if isinstance(frames, FolderFrames) else None,
                     state.get("gaps"), state.get("damaged"), state.get("notes"))


def _suggested(folder: Path, names: list[str], stems: list[str], keys: frozenset[int]) -> tuple[tuple[int, float | None], ...]:
    """The run's frames that ``suggest.txt`` names (by name or stem, :func:`pcreg.runs.files.read_suggestions`),
    as positions, in its order, with the predicted error given there; a key frame (labelled since) is none to label."""
    from .runs.files import read_suggestions

    where = {**{s: t for t, s in enumerate(stems)}, **{n: t for t, n in enumerate(names)}}
    return tuple((where[name], error) for name, error in read_suggestions(folder, set(where)) if where[name] not in keys)


def overlay(image: np.ndarray, labels: np.ndarray, confidence: np.ndarray | None = None, *,
            low: float = LOW_CONFIDENCE, key: bool = False, table: ClassTable = DEFAULT_TABLE) -> np.ndarray:
    """``image`` (H, W, 3) uint8 RGB with ``labels`` (H, W) class ids of ``table`` drawn over it (each known
    class in its table colour, :data:`ALPHA`; unknown left clear); where ``confidence`` (H, W) uint8, 255 x the
    probability that the label is right, is below ``low``, dark diagonal hatching. ``key``: a key frame,
    framed in blue. Returns a new (H, W, 3) uint8 RGB image."""
    if labels.shape != image.shape[:2]:
        raise InputError(f"labels are {labels.shape[1]}x{labels.shape[0]}, the frame {image.shape[1]}x{image.shape[0]}")
    out = image.astype(np.float32)
    for c in table.known:
        colour = c.colour
        m = labels == c.id
        out[m] = (1 - ALPHA) * out[m] + ALPHA * np.asarray(colour, np.float32)
    if confidence is not None:
        if confidence.shape != labels.shape:
            raise InputError("a confidence map of another size than its labels")
        h, w = labels.shape
        yy, xx = np.mgrid[0:h, 0:w]
        hatch = ((xx + yy) % 8 < 3) & _unsure(labels, confidence, table, low)
        out[hatch] *= 0.3
    if key:
        b = _border(labels.shape)
        out[:b], out[-b:], out[:, :b], out[:, -b:] = (59, 130, 246), (59, 130, 246), (59, 130, 246), (59, 130, 246)
    return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def _unsure(labels: np.ndarray, confidence: np.ndarray, table: ClassTable, low: float = LOW_CONFIDENCE) -> np.ndarray:
    """Where a known label's ``confidence`` (uint8, 255 x the probability) is below ``low``: what
    :func:`overlay` hatches."""
    return (confidence.astype(np.float32) < low * 255.0) & (labels != table.unknown)


def _border(shape: tuple[int, ...]) -> int:
    """The width in pixels of a key frame's blue frame in a frame of ``shape``."""
    return max(2, min(shape[:2]) // 60)


def class_figures(review: RunReview, t: int, shape: tuple[int, ...] | None = None) -> list[dict]:
    """Frame ``t``'s classes as the review's legend shows them: each known class's share of the frame's
    pixels (%), its predicted IoU from the confidence (None for a key frame, or a class the step did not label) and,
    in a run scored with ``--truth``, its IoU against the truth (``truth_iou``; None where the step has none).
    Labels of another size than ``shape`` (the run's, when given) are an :class:`InputError`, as in the overlay."""
    from .export import read_labels

    labels = read_labels(review.labels_path(t), review.table)
    if shape is not None and labels.shape != shape:
        raise InputError(f"{review.labels_path(t)}: labels of {labels.shape[1]}x{labels.shape[0]}, the run's are "
                         f"{shape[1]}x{shape[0]} (not a label image this run wrote)")
    counts = np.bincount(labels.ravel(), minlength=256)
    iou = review.ious[t] if t < len(review.ious) else None
    truth = review.truth_at(t)
    scored = None if truth is None else truth.iou
    return [{"id": c.id, "share": 100.0 * float(counts[c.id]) / max(1, labels.size),
             "iou": None if iou is None else iou.get(c.id), "truth_iou": None if scored is None else scored.get(c.id)}
            for c in review.table.known]


def shown_classes(review: RunReview) -> list[int]:
    """The ids of the known classes the run's frames show (a pixel or more in a frame's labels), in the table's
    order: what the review's legend lists, where a table of 150 classes labels a few in a run.

    A step's predicted IoU names exactly the classes its labels hold, so only the label files of the frames
    without one are read (the key frames; every frame of a two-class run of an earlier pcreg, until every known
    class has been seen): a run of thousands of frames is not read whole before its page
    shows. A label file that cannot be read is passed over (its frame says why when it is shown)."""
    from .export import read_labels

    known = [c.id for c in review.table.known]
    seen = np.zeros(256, bool)
    unread = []
    for t in range(len(review.names)):
        iou = review.ious[t] if t < len(review.ious) else None
        if iou is None or t in review.keys:
            unread.append(t)
        else:
            seen[[k for k in iou if 0 <= k < 256]] = True
    for t in unread:
        if seen[known].all():
            break
        try:
            seen |= np.bincount(read_labels(review.labels_path(t), review.table).ravel(), minlength=256) > 0
        except InputError:
            continue
    return [k for k in known if seen[k]]


def read_overlay(review: RunReview, t: int, image: np.ndarray) -> np.ndarray:
    """Frame ``t`` of ``review`` (its ``image``, RGB) with its labels and confidence drawn over it."""
    labels, conf = _frame_labels(review, t, image)
    return overlay(image, labels, conf, key=t in review.keys, table=review.table)


def video_frame(review: RunReview, t: int, image: np.ndarray) -> tuple[np.ndarray, Legend]:
    """Frame ``t`` of ``review`` as the overlay video shows it: :func:`read_overlay`'s picture with its legend
    drawn in (:func:`pcreg.legend.draw_legend`: the frame's name, its figures, the classes its labels show, the
    hatching when a label is hatched), and where the legend went."""
    labels, conf = _frame_labels(review, t, image)
    drawn = overlay(image, labels, conf, key=t in review.keys, table=review.table)
    hatched = conf is not None and bool(_unsure(labels, conf, review.table).any())
    title = review.names[t] if review.kind == "folder" else f"frame {review.names[t]}"
    return draw_legend(drawn, labels, title=title + (" (key frame)" if t in review.keys else ""), table=review.table,
                       hatched_below=LOW_CONFIDENCE if hatched else None, inset=_border(labels.shape), **frame_figures(review, t))


def frame_figures(review: RunReview, t: int) -> dict:
    """Frame ``t``'s figures as its legend in the overlay video gives them (:func:`pcreg.legend.legend_figures`: its
    predicted error and each class's predicted IoU, and against the truth in a run scored with ``--truth``)."""
    truth = review.truth_at(t)
    return legend_figures(review.errors[t] if t < len(review.errors) else None, review.ious[t] if t < len(review.ious) else None,
                          None if truth is None else truth.error, None if truth is None else truth.iou)


def _frame_labels(review: RunReview, t: int, image: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Frame ``t``'s labels (H, W) and its confidence map (None: the run has none for it), read from the run."""
    from .export import read_labels
    from .runs.files import read_confidence

    labels = read_labels(review.labels_path(t), review.table)
    if labels.shape != image.shape[:2]:
        raise InputError(f"{review.labels_path(t)}: labels of {labels.shape[1]}x{labels.shape[0]}, the frame is "
                         f"{image.shape[1]}x{image.shape[0]} (not a label image this run wrote)")
    conf_path = review.confidence_path(t)
    conf = None if conf_path is None else read_confidence(conf_path, labels.shape, f"not a confidence map of {review.labels_path(t).name}'s")
    return labels, conf


def _video_rate(review: RunReview) -> float | None:
    """The frames per second of a review's video, every chosen frame counted (None: a folder, or a video
    that does not say)."""
    import av

    if review.kind != "video":
        return None
    try:
        with av.open(str(review.source), metadata_errors="ignore") as container:
            rate = container.streams.video[0].average_rate
    except (av.FFmpegError, IndexError):
        return None
    every = int((review.selection or {}).get("every", 1))
    return float(rate) / every if rate else None


def _encoder() -> str:
    """H.264 (libx264) where this FFmpeg has it, else MPEG-4 part 2 (FFmpeg's own ``mpeg4``)."""
    import av

    try:
        av.codec.Codec("libx264", "w")
    except (av.FFmpegError, ValueError):
        return "mpeg4"
    return "libx264"


#: The overlay's rates, frames per second: its stream stores a fraction of denominator <= 1000 (less: 0, then 24 fps).
MIN_FPS, MAX_FPS = 0.001, 1000.0


def write_overlay_video(review: RunReview, path: str | Path, *, fps: float | None = None,
                        note: Callable[[str], object] | None = None) -> int:
    """Every frame of ``review`` with its labels drawn over it and its legend drawn in (:func:`video_frame`) as
    an MP4 at ``path`` of the frames' size (H.264; written to a temporary file beside it, then renamed: what an
    overlay of that name killed mid-write left is removed first); frames of odd size are padded by a pixel. ``fps``: frames per second (default: a video's own rate, divided by the
    run's ``--every``; 10 for a folder). The source is read straight through, once. A run whose video skips frames
    by its times, has frames that decode with errors or met other notes reading them says so in the video's comment,
    one line each (:meth:`RunReview.said`); a review of no frame is refused. ``note`` is told, once the video is written, when a
    frame is too small for its classes' legend (it shows its name alone). Returns the number of frames written."""
    from fractions import Fraction

    import av

    from ._runner import progress
    from .outputs import atomic_path, remove_leftovers

    if not review.names:  # an MP4 of no frame is no video a player opens
        raise InputError(f"{review.folder}: holds no labelled frame: no overlay video to write")
    fps = max(_video_rate(review) or 10.0, MIN_FPS) if fps is None else check_float(fps, "fps", lo=MIN_FPS, hi=MAX_FPS)
    codec = _encoder()
    path = Path(path)
    remove_leftovers(path.parent, [path.name])  # of an overlay of this name killed mid-write
    n = 0
    small: str | None = None  # told once the video is written: a video refused says one line, its refusal
    images = FrameImages(review)  # no thread: a video is read through frames()
    try:
        with atomic_path(path) as tmp, av.open(tmp, "w", format="mp4") as container, \
                progress(total=len(review.names), desc="frames", disable=None) as bar:
            if review.said():  # what the run's review says of its frames, one line each, in the video's comment
                container.metadata["comment"] = "\n".join(review.said())
            stream = None
            for t, image in images.frames():
                drawn, legend = video_frame(review, t, image)
                h, w = drawn.shape[:2]
                if not legend.complete and small is None:
                    small = f"{path}: frame {review.names[t]} ({w}x{h}) is too small for the legend of its classes: " \
                            "such frames show their name alone"
                if stream is None:
                    stream = container.add_stream(codec, rate=Fraction(fps).limit_denominator(1000))
                    stream.width, stream.height = w + w % 2, h + h % 2
                    stream.pix_fmt = "yuv420p"
                    if codec == "libx264":
                        stream.options = {"crf": "20", "preset": "veryfast"}
                    else:
                        stream.bit_rate = max(1_000_000, int(w * h * fps))  # a bit a pixel a frame
                if (h + h % 2, w + w % 2) != (stream.height, stream.width):
                    raise InputError(f"{review.source}: frame {review.names[t]} is {w}x{h}, the first {stream.width}x{stream.height}")
                if w % 2 or h % 2:
                    drawn = np.pad(drawn, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
                for packet in stream.encode(av.VideoFrame.from_ndarray(drawn, format="rgb24")):
                    container.mux(packet)
                n += 1
                bar.update(1)
            if stream is not None:
                for packet in stream.encode():
                    container.mux(packet)
    finally:
        images.close()
    if small is not None and note is not None:
        note(small)
    return n


if not TYPE_CHECKING:  # a module __getattr__ would be mypy's for every name: a misspelt one would pass
    __getattr__ = moved(__name__, {"SUGGEST": "pcreg.runs.files"})
