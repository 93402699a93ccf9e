"""What a resumed ``pcreg run`` checks of its frames against what it labelled: a folder's frame renamed, added or
written again since (its file's size in bytes), so that a run never goes on from, or keeps labels of, frames that are no
longer there. A video's file is checked whole (:func:`pcreg.runs.video_file.keep_video`)."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError, OutputError
from .files import STEPS, parse_steps, step_lines
from .state import STATE

__all__ = ["check_same_inputs", "check_same_frames", "check_same_frame", "frame_bytes", "frame_moved", "moved_error"]


def check_same_inputs(frames, out: Path, identity: dict | None, done: int, labels_changed: bool) -> None:
    """Refuse to continue the run from one label image in ``out`` (``identity``: its run.json's ``run``, ``done`` the
    frames it counts) whose key labels changed since it began (run.json's ``key_labels``, their
    :func:`~pcreg.runs.files.label_digest`), or whose frames folder now holds fewer frames than it labelled: its
    frames would mix two runs."""
    labels = identity.get("labels") if identity else None
    if labels_changed:
        raise OutputError(f"{labels}: the key frame's labels changed since the run in {out} began; "
                          "use --force to start over")
    if frames.kind == "folder" and done > len(frames):
        raise OutputError(f"{out / STATE} counts {done} frames labelled, {frames.path} now holds "
                          f"{len(frames)}{' chosen' if frames.selection.to_dict() else ''}: the frames "
                          "changed since the run began; use --force to start over")


def check_same_frames(frames, out: Path, key_frame: str, key_bytes) -> None:
    """Refuse to continue the run from one label image in ``out`` over a steps.jsonl line pcreg run did not write (the
    export would refuse it, :func:`~pcreg.runs.files.parse_steps`), a frame renamed or a frame's file changed
    (:func:`check_same_frame`): the key frame against run.json's ``key_bytes``, each labelled frame against its
    line's ``bytes``."""
    steps = parse_steps(out / STEPS, step_lines(out))
    check_same_frame(frames, out, 0, {"name": key_frame, "bytes": key_bytes}, key=True)
    for step in steps:  # every line read, a video's too
        check_same_frame(frames, out, int(step["frame"]), step)


def frame_bytes(frames, t: int) -> int | None:
    """The size in bytes of frame ``t``'s file, for a folder's ``frames`` (None for a video's)."""
    return frames.where(t).stat().st_size if frames.kind == "folder" else None


def check_same_frame(frames, out: Path, t: int, step: dict, *, key: bool = False) -> None:
    """An :class:`~pcreg.errors.OutputError` when the run in ``out`` labelled ``step["name"]`` as frame ``t`` of a folder
    that now holds another there (renamed, added), or when the frame's file is no longer the size in bytes it was
    (``step["bytes"]``, where the step kept it: the frame was written again, its labels are of the frame as it was).
    ``key``: frame ``t`` is a key frame, which the run labelled others from."""
    if frames.kind != "folder" or t >= len(frames):
        return
    name, before = step.get("name"), step.get("bytes")
    if isinstance(name, str) and frames.name(t) != name:
        raise OutputError(f"{out / STATE}: the run labelled {name} as frame {t}, which {frames.path} "
                          f"now holds as {frames.name(t)}: the frames changed since the run began; "
                          "use --force to start over")
    if type(before) is int and (now := frame_bytes(frames, t)) != before:
        what = "labelled from it" if key else "labelled it"
        whose = "the labels carried from it are" if key else "its labels are"
        raise OutputError(f"{frames.where(t)}: changed since the run in {out} {what} ({before} bytes "
                          f"then, {now} now): {whose} of the frame as it was; use --force to start over")


def frame_moved(frames, t: int, name: str) -> bool:
    """Whether the frame a run labelled as ``name`` at position ``t`` is no longer there in its frames folder (a
    frame added, removed or renamed since: the review would draw one frame's labels over another, or call a frame
    never labelled one whose step is lost); never for a video, whose frames are named by their number."""
    from ..datasets.sources import FolderFrames

    return isinstance(frames, FolderFrames) and t < len(frames) and frames.name(t) != name


def moved_error(frames, folder: Path, t: int, name: str) -> InputError:
    """What the review says of a frame the run in ``folder`` labelled as ``name`` at position ``t`` (:func:`frame_moved`)."""
    return InputError(f"{frames.path}: holds {frames.name(t)} as frame {t}, which the run in {folder} labelled as "
                      f"{name}: the frames changed since the run (a frame added, removed or renamed)")
