"""What a resumed ``pcreg run`` checks of its frames against what it labelled: a folder's frame renamed, added or
written again since (its file's size in bytes and, where its modification time changed, a digest of its bytes:
:func:`frame_stamp`), so that a run never goes on from, or keeps labels of, frames that are no longer there. A video's
file is checked by its fingerprint (:func:`pcreg.runs.video_file.keep_video`)."""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError, OutputError
from .files import STEPS, parse_steps, step_lines
from .state import STATE

__all__ = ["FramesAsLabelled", "check_source", "check_same_inputs", "check_same_frames", "check_same_frame", "check_same_truth", "check_key_files", "frame_bytes",
           "frame_stamp", "file_digest", "key_contents", "frame_moved", "moved_error"]


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


def check_same_frames(frames, out: Path, key_frame: str, key_bytes, contents=None, truth=None) -> None:
    """Refuse to continue the run from one label image in ``out`` over a steps.jsonl line pcreg run did not write (the
    export would refuse it, :func:`~pcreg.runs.files.parse_steps`), a frame renamed or a frame's file changed
    (:func:`check_same_frame`): the key frame against run.json's ``key_bytes`` and ``key_contents`` (``contents``),
    each labelled frame against its line's ``bytes``, ``mtime_ns`` and ``digest``, and its ``truth`` map against its
    line's ``truth_digest`` (:func:`check_same_truth`)."""
    steps = parse_steps(out / STEPS, step_lines(out))
    check_same_frame(frames, out, 0, {"name": key_frame, "bytes": key_bytes, **_contents(contents, key_frame)}, key=True)
    for step in steps:  # every line read, a video's too
        check_same_frame(frames, out, int(step["frame"]), step)
        check_same_truth(truth, out, step)


def check_same_truth(truth, out: Path, step: dict) -> None:
    """An :class:`~pcreg.errors.OutputError` when the truth map (of ``truth``, a
    :class:`~pcreg.runs.inputs.TruthMaps`) that the run in ``out`` scored ``step``'s frame against no longer holds the
    labels it did (its line's ``truth_digest``, :func:`~pcreg.runs.files.label_digest`; a map saved again with the
    same labels is the same): the run's error would mix scores against two truths. A map gone is the
    :class:`~pcreg.errors.InputError` of any frame without one."""
    digest = step.get("truth_digest")
    if truth is None or not isinstance(digest, str):
        return
    t = int(step["frame"])
    now = file_digest(truth.path(t)) if len(digest) == 32 else truth.digest(t)  # 32: the file's bytes, as first kept
    if now != digest:
        raise OutputError(f"{truth.path(t)}: changed since the run in {out} scored {step.get('name', 'its frame')} "
                          "against it: its error is against the truth as it was; use --force to start over")


def check_key_files(frames, out: Path, state: dict, keys) -> None:
    """Refuse to continue the key-frames run in ``out`` whose key frames ``keys`` (positions) changed since they were
    labelled from (:func:`check_same_frame`, against run.json's ``key_bytes`` and ``key_contents`` in ``state``)."""
    sizes = state.get("key_bytes") or {}
    for k in sorted(keys):
        name = frames.name(k)
        check_same_frame(frames, out, k, {"name": name, "bytes": sizes.get(name), **_contents(state.get("key_contents"), name)},
                         key=True)


def _contents(contents, name: str) -> dict:
    """run.json's ``key_contents`` entry of the key frame ``name`` (``mtime_ns`` and ``digest``), or {}."""
    entry = contents.get(name) if isinstance(contents, dict) else None
    return {k: entry.get(k) for k in ("mtime_ns", "digest")} if isinstance(entry, dict) else {}


def frame_bytes(frames, t: int) -> int | None:
    """The size in bytes of frame ``t``'s file, for a folder's ``frames`` (None for a video's)."""
    return frames.where(t).stat().st_size if frames.kind == "folder" else None


def file_digest(path: Path) -> str:
    """A digest of the file's bytes (BLAKE2b, 16 bytes, in hex)."""
    import hashlib

    return hashlib.blake2b(Path(path).read_bytes(), digest_size=16).hexdigest()


def frame_stamp(frames, t: int) -> dict:
    """What a resumed run checks frame ``t``'s file against, for a folder's ``frames``: its size in ``bytes``, its
    modification time (``mtime_ns``) and a ``digest`` of its bytes ({} for a video's). The size alone misses a frame
    written again to the same size (uncompressed BMP or PPM frames of another clip); the digest is read again on a
    resume only where the modification time changed (in a folder copied without its times, every frame, on each
    resume: the steps keep the times the run saw)."""
    if frames.kind != "folder":
        return {}
    path = frames.where(t)
    st = path.stat()
    return {"bytes": st.st_size, "mtime_ns": st.st_mtime_ns, "digest": file_digest(path)}


def key_contents(frames, keys) -> dict:
    """run.json's ``key_contents``: each key frame's (positions ``keys``) ``mtime_ns`` and ``digest``, by name."""
    stamps = {frames.name(k): frame_stamp(frames, k) for k in keys}
    return {name: {"mtime_ns": s["mtime_ns"], "digest": s["digest"]} for name, s in stamps.items() if s}


def check_same_frame(frames, out: Path, t: int, step: dict, *, key: bool = False) -> None:
    """An :class:`~pcreg.errors.OutputError` when the run in ``out`` labelled ``step["name"]`` as frame ``t`` of a folder
    that now holds another there (renamed, added), or when the frame's file is no longer the size in bytes it was
    (``step["bytes"]``, where the step kept it: the frame was written again, its labels are of the frame as it was), or,
    its modification time changed (``step["mtime_ns"]``), no longer holds the bytes it did (``step["digest"]``).
    ``key``: frame ``t`` is a key frame, which the run labelled others from."""
    if frames.kind != "folder" or t >= len(frames):
        return
    name = step.get("name")
    if isinstance(name, str) and frames.name(t) != name:
        raise OutputError(f"{out / STATE}: the run labelled {name} as frame {t}, which {frames.path} "
                          f"now holds as {frames.name(t)}: the frames changed since the run began; "
                          "use --force to start over")
    changed = frame_changed(frames, out, t, step, key=key)
    if changed is not None:
        raise OutputError(f"{changed}; use --force to start over")


def frame_changed(frames, out: Path, t: int, step: dict, *, key: bool = False) -> str | None:
    """What is said of frame ``t`` of a folder's ``frames`` whose file is no longer what the run in ``out`` labelled
    (:func:`check_same_frame`'s ``step``: its size in bytes, or where its modification time changed its digest);
    None where it still is, or the step kept neither."""
    if frames.kind != "folder" or t >= len(frames):
        return None
    what = "labelled from it" if key else "labelled it"
    whose = "the labels carried from it are" if key else "its labels are"
    before = step.get("bytes")
    if type(before) is int and (now := frame_bytes(frames, t)) != before:
        return (f"{frames.where(t)}: changed since the run in {out} {what} ({before} bytes then, {now} now): "
                f"{whose} of the frame as it was")
    mtime, digest = step.get("mtime_ns"), step.get("digest")
    if type(mtime) is int and isinstance(digest, str) and frames.where(t).stat().st_mtime_ns != mtime \
            and file_digest(frames.where(t)) != digest:
        return f"{frames.where(t)}: changed since the run in {out} {what} (the same size, other contents): {whose} of the frame as it was"
    return None


def frame_moved(frames, t: int, name: str) -> bool:
    """Whether the frame a run labelled as ``name`` at position ``t`` is no longer there in its frames folder (a
    frame added, removed or renamed since: the review would draw one frame's labels over another, or call a frame
    never labelled one whose step is lost); never for a video, whose frames are named by their number."""
    from ..datasets.sources import FolderFrames

    return isinstance(frames, FolderFrames) and (t >= len(frames) or frames.name(t) != name)


def moved_error(frames, folder: Path, t: int, name: str) -> InputError:
    """What the review says of a frame the run in ``folder`` labelled as ``name`` at position ``t`` (:func:`frame_moved`)."""
    if t >= len(frames):  # removed from the end (as the run resumed would refuse it)
        chosen = " chosen" if frames.selection.to_dict() else ""
        return InputError(f"{frames.path}: holds {len(frames)} frames{chosen}, the run in {folder} labelled {name} as frame "
                          f"{t}: frames were removed since the run; put them back, or label the frames again (pcreg run "
                          "... --force)")
    return InputError(f"{frames.path}: holds {frames.name(t)} as frame {t}, which the run in {folder} labelled as "
                      f"{name}: the frames changed since the run (a frame added, removed or renamed)")


class FramesAsLabelled:
    """Whether the frames of a run's source are still those it labelled, step by step (:meth:`step`), then
    :meth:`check`: an :class:`~pcreg.errors.InputError` for a frame written again since (:func:`frame_changed`) at once,
    and for a frame added, removed or renamed since (:func:`frame_moved`, from ``key_frame`` at position 0 of a run from
    one label image on) the earliest, once every step was seen, or a key frame of a key-frames run (``keys``, their names)
    gone. ``doing``: what the message says to label it again for (``"review"``, ``"export"``). A video's frames are never
    said changed or moved."""

    def __init__(self, frames, folder: Path, doing: str, key_frame: str | None = None, keys=()) -> None:
        self.frames, self.folder, self.doing = frames, folder, doing
        self.keys = tuple(map(str, keys))  # a key-frames run's key frames, which have no step
        self.moved = [(0, key_frame)] if key_frame is not None and frame_moved(frames, 0, key_frame) else []
        self.key_frame = key_frame
        self.named: dict[int, str] = {} if key_frame is None else {0: key_frame}  # each frame's name, as the run said it

    def step(self, step: dict) -> None:
        t, name = step["frame"], str(step["name"])
        if self.named.setdefault(t, name) != name:  # one frame, two names: the steps edited, not the frames
            said = f"on one line and {name} on another" if t or self.key_frame is None else f"in run.json (its key frame) and {name} on a line"
            raise InputError(f"{self.folder / STEPS}: frame {t} is {self.named[t]} {said} (not a steps.jsonl pcreg run wrote)")
        if frame_moved(self.frames, t, name):
            self.moved.append((t, name))
        elif (changed := frame_changed(self.frames, self.folder, t, step)) is not None:
            raise InputError(f"{changed}; label it again (pcreg run ... --force) to {self.doing} it")

    def check(self) -> None:
        from ..datasets.sources import FolderFrames

        if self.moved:
            raise moved_error(self.frames, self.folder, *min(self.moved))
        if self.keys and isinstance(self.frames, FolderFrames):
            held = {self.frames.name(t) for t in range(len(self.frames))}
            gone = [k for k in self.keys if k not in held]
            if gone:
                raise InputError(f"{self.frames.path}: no longer holds {gone[0]}, a key frame of the run in {self.folder}: "
                                 "frames were removed since the run; put them back, or label the frames again (pcreg "
                                 "run ... --force)")


def check_source(state: dict, kind: str, source: Path, folder: Path) -> None:
    """For the review of the run in ``folder`` (``state`` its run.json): an :class:`~pcreg.errors.InputError` when
    the run's ``source`` (its ``kind``, video or folder) is gone, or is a video written over since
    (:func:`~pcreg.runs.video_file.check_labelled_video`: its frames are not those labelled; a folder's frames are
    checked step by step)."""
    from ..outputs import shell_word
    from .state import can_move
    from .video_file import check_labelled_video

    if not source.exists():
        gone = f"{folder / STATE}: the run's {kind} {source} is gone (the frames are read from there)"
        if not can_move(state, kind):  # begun before a run kept what it read of its inputs
            raise InputError(f"{gone}; put it back there: this run was begun by an earlier pcreg, which did not keep what it "
                             "read of its inputs, so it cannot be followed to a new place (pcreg run ... --force labels the frames again)")
        raise InputError(f"{gone}; moved with its project? the same pcreg run with the {kind}'s new path and --out {shell_word(folder)} "
                         "names the new places in run.json, and goes on from what was labelled")
    if kind == "video":
        check_labelled_video(state, source, folder, "review")
