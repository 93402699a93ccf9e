"""A video run's file as its run.json names it: ``video_file``, a fingerprint cheap to take and hard to fool (the
file's ``size``, its modification time ``mtime_ns``, a ``sha256`` of its first and last MiB and a ``spread``, the
sha256 of :data:`SPREAD` blocks of :data:`BLOCK` bytes evenly spaced through it), and ``video_end``,
the count of frames done when decoding found the end of the run's frames (the video's end, or ``--stop``).

A rerun of a run that labelled its video to its end, over the same file, is known finished from run.json alone: no
frame decoded to find that none is left, no carry read (:func:`labelled_to_end`). A resume over another file at the
video's path (other bytes at either end or in a block spread through it, or fewer of them) is refused (:func:`keep_video`): its frames would be
labelled from the other video's carry. A file only appended to (a recording still growing) goes on; a file whose
fingerprint changed otherwise (copied, touched) goes on as a run.json without the fields does, decoding its way to its
first frame not done, and its fingerprint is kept anew. A file of a codec whose frames are all of one size (raw video,
v210) can change inside without changing its size or its ends: the spread sees a change of more than a 255th of the
file for certain (its blocks are that far apart, start to start), and of less where it covers one of its blocks. A
run.json without ``spread`` (from an earlier pcreg) is checked by the rest, and gains it where the run next writes its
run.json (a rerun of a run labelled to its end writes nothing).
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Generator, Iterator

from ..errors import OutputError

__all__ = ["MIB", "SPREAD", "BLOCK", "fingerprint", "keep_video", "check_kept", "labelled_to_end", "mark_end", "video_file_problem",
           "check_labelled_video"]

#: How much of each end of the file its fingerprint reads.
MIB = 1 << 20
#: How many blocks the ``spread`` reads, and of how many bytes: 4 MiB in all, in 256 reads.
SPREAD, BLOCK = 256, 16 << 10


def _digest(path: Path, size: int) -> str:
    """The sha256 of the first MiB of the file at ``path`` and of the last MiB of its first ``size`` bytes (the whole
    of them when there are at most two MiB)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        h.update(fh.read(min(MIB, size)))
        if size > MIB:
            fh.seek(max(MIB, size - MIB))
            h.update(fh.read(size - max(MIB, size - MIB)))
    return h.hexdigest()


def _spread(path: Path, size: int) -> str:
    """The sha256 of :data:`SPREAD` blocks of :data:`BLOCK` bytes evenly spaced through the first ``size`` bytes of the
    file at ``path``, the first at its start and the last at their end (fewer where blocks would overlap)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for at in sorted({(size - BLOCK) * i // (SPREAD - 1) for i in range(SPREAD)} if size > BLOCK else {0}):
            fh.seek(at)
            h.update(fh.read(min(BLOCK, size)))
    return h.hexdigest()


def fingerprint(path: Path) -> dict:
    """The video file at ``path`` as run.json's ``video_file`` names it: ``{"size", "mtime_ns", "sha256", "spread"}``."""
    st = Path(path).stat()
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns, "sha256": _digest(Path(path), st.st_size),
            "spread": _spread(Path(path), st.st_size)}


def _same_bytes(before: dict, now: dict) -> bool:
    """Whether fingerprints ``before`` and ``now`` name the same bytes (``before`` without a ``spread``: by the rest)."""
    return (before["size"], before["sha256"], before.get("spread", now["spread"])) == (now["size"], now["sha256"], now["spread"])


def _appended(before: dict, path: Path, now: dict) -> bool:
    """Whether the file at ``path`` (fingerprinted ``now``) is the file ``before`` names with bytes added at its end."""
    return (now["size"] > before["size"] and _digest(path, before["size"]) == before["sha256"]
            and ("spread" not in before or _spread(path, before["size"]) == before["spread"]))


def keep_video(state: dict, frames, out: Path) -> bool:
    """For a run over a video (``frames``, a :class:`~pcreg.datasets.sources.VideoFrames`) opening with ``state`` (its
    run.json, resumed or new): an :class:`~pcreg.errors.OutputError` when run.json names another file at the video's
    path, else its fingerprint now kept in ``state`` (``video_end`` forgotten when it changed). Whether the file grew
    since (bytes appended: frames after those labelled to its end)."""
    now, before = fingerprint(frames.path), state.get("video_file")
    if before == now:
        return False
    if before is not None and "spread" not in before and all(now.get(k) == v for k, v in before.items()):
        state["video_file"] = now  # an earlier pcreg's fingerprint of this very file: only the spread is new
        return False
    grown = before is not None and _appended(before, frames.path, now)
    if before is not None and not grown and not _same_bytes(before, now):
        raise OutputError(f"{frames.path}: not the video the run in {out} began on (its size or bytes changed since: "
                          f"{before['size']} bytes then, {now['size']} now); use --force to start over")
    state["video_file"] = now
    state.pop("video_end", None)
    return grown


def labelled_to_end(state: dict) -> bool:
    """Whether a run from one label image (its run.json, ``state``, after :func:`keep_video`) labelled its frames to
    their end in the very file its video is now: no frame is left."""
    return "video_file" in state and state.get("video_end") == state["done"]


def _written_over(state: dict, path: Path) -> tuple[int, int] | None:
    """``(size then, size now)`` when the video file at ``path`` is no longer the one run.json (``state``) names in
    ``video_file``, nor it with bytes appended; None when it is, or run.json names none (an earlier pcreg's)."""
    before = state.get("video_file")
    if before is None:
        return None
    now = fingerprint(path)
    if _same_bytes(before, now) or _appended(before, path, now):
        return None
    return before["size"], now["size"]


def check_kept(state: dict, frames, out: Path) -> None:
    """An :class:`~pcreg.errors.OutputError` when the video file (``frames.path``) is no longer the one run.json names
    (``state``'s ``video_file``) nor it with bytes appended: written again while the run in ``out`` decoded it, so that
    the frames it labelled may be of two videos (a resume would refuse the file; the run that labelled them said
    nothing)."""
    sizes = _written_over(state, frames.path)
    if sizes is not None:
        raise OutputError(f"{frames.path}: written again while the run in {out} labelled it ({sizes[0]} bytes when "
                          f"it began, {sizes[1]} now): its labels may be of two videos; use --force to start over")


def check_labelled_video(state: dict, path: Path, out: Path, doing: str) -> None:
    """For a reader of the run in ``out`` over the video at ``path`` (``state`` its run.json): an
    :class:`~pcreg.errors.InputError` when the file is no longer the one the run labelled nor it with bytes appended
    (written over since: another video, or the same re-encoded), whose frames its labels are not of. ``doing``: what the
    message says to label it again for (``"review"``, ``"export"``). A run.json without ``video_file`` (from an earlier
    pcreg) is not checked."""
    from ..errors import InputError

    sizes = _written_over(state, path)
    if sizes is not None:
        raise InputError(f"{path}: not the video the run in {out} labelled (its size or bytes changed since: {sizes[0]} "
                         f"bytes then, {sizes[1]} now), so its labels are not of these frames; label it again (pcreg run "
                         f"... --force) to {doing} it")


def mark_end(state: dict, frames, out: Path) -> None:
    """Keep in ``state`` that decoding found the end of the run's frames with ``state["done"]`` of them done, in the
    file the run began on (:func:`check_kept`)."""
    check_kept(state, frames, out)
    state["video_end"] = state["done"]


def video_file_problem(state: dict) -> str | None:
    """The first of run.json's ``video_file`` and ``video_end`` (None when there is none) that is not as pcreg run
    writes it, or None."""
    f = state.get("video_file")
    counts = isinstance(f, dict) and type(f.get("size")) is int and f["size"] >= 0 and type(f.get("mtime_ns")) is int
    digests = [f.get("sha256"), f.get("spread", "0" * 64)] if isinstance(f, dict) else []
    if f is not None and not (counts and all(isinstance(d, str) and len(d) == 64 and set(d) <= set("0123456789abcdef")
                                             for d in digests)):
        return "video_file"
    end = state.get("video_end")
    if end is not None and not (type(end) is int and end >= 1 and f is not None):
        return "video_end"
    return None


def decoded_to(frames, start: int) -> Iterator:
    """``frames.frames(start)``: a video's decoded here up to its frame at ``start``, under a bar of the frames decoded
    on the way (a resumed run, or one from ``--start``, decodes its video from the first frame, minutes for an hour of
    video, where the run's bar of frames stood at 0), the rest as the caller reads them; a folder's as they are."""
    if frames.kind != "video" or frames.selection.index(start) == 0:
        return frames.frames(start)
    from .._runner import progress

    with progress(total=frames.selection.index(start), desc=f"decoding to frame {frames.name(start)}", unit="frame",
                  disable=None) as bar:
        todo = frames.frames(start, passing=lambda i: bar.update(1))
        first = next(todo, None)
    return todo if first is None else _going_on(first, todo)


def _going_on(first, rest: Generator) -> Generator:
    """``first``, then ``rest``; closing it closes ``rest`` (a video's file)."""
    try:
        yield first
        yield from rest
    finally:
        rest.close()
