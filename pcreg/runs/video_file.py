"""A video run's file as its run.json names it: ``video_file``, a fingerprint cheap to take and hard to fool (the
file's ``size``, its modification time ``mtime_ns`` and a ``sha256`` of its first and last MiB), and ``video_end``,
the count of frames done when decoding found the end of the run's frames (the video's end, or ``--stop``).

A rerun of a run that labelled its video to its end, over the same file, is known finished from run.json alone: no
frame decoded to find that none is left, no carry read (:func:`labelled_to_end`). A resume over another file at the
video's path (other bytes at either end, or fewer of them) is refused (:func:`keep_video`): its frames would be
labelled from the other video's carry. A file only appended to (a recording still growing) goes on; a file whose
fingerprint changed otherwise (copied, touched) goes on as a run.json without the fields does, decoding its way to its
first frame not done, and its fingerprint is kept anew.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from ..errors import OutputError

__all__ = ["MIB", "fingerprint", "keep_video", "check_kept", "labelled_to_end", "mark_end", "video_file_problem"]

#: How much of each end of the file its fingerprint reads.
MIB = 1 << 20


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


def fingerprint(path: Path) -> dict:
    """The video file at ``path`` as run.json's ``video_file`` names it: ``{"size", "mtime_ns", "sha256"}``."""
    st = Path(path).stat()
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns, "sha256": _digest(Path(path), st.st_size)}


def _appended(before: dict, path: Path, now: dict) -> bool:
    """Whether the file at ``path`` (fingerprinted ``now``) is the file ``before`` names with bytes added at its end."""
    return now["size"] > before["size"] and _digest(path, before["size"]) == before["sha256"]


def keep_video(state: dict, frames, out: Path) -> bool:
    """For a run over a video (``frames``, a :class:`~pcreg.datasets.sources.VideoFrames`) opening with ``state`` (its
    run.json, resumed or new): an :class:`~pcreg.errors.OutputError` when run.json names another file at the video's
    path, else its fingerprint now kept in ``state`` (``video_end`` forgotten when it changed). Whether the file grew
    since (bytes appended: frames after those labelled to its end)."""
    now, before = fingerprint(frames.path), state.get("video_file")
    if before == now:
        return False
    grown = before is not None and _appended(before, frames.path, now)
    if before is not None and not grown and (before["size"], before["sha256"]) != (now["size"], now["sha256"]):
        raise OutputError(f"{frames.path}: not the video the run in {out} began on (its size or bytes changed since: "
                          f"{before['size']} bytes then, {now['size']} now); use --force to start over")
    state["video_file"] = now
    state.pop("video_end", None)
    return grown


def labelled_to_end(state: dict) -> bool:
    """Whether a run from one label image (its run.json, ``state``, after :func:`keep_video`) labelled its frames to
    their end in the very file its video is now: no frame is left."""
    return "video_file" in state and state.get("video_end") == state["done"]


def check_kept(state: dict, frames, out: Path) -> None:
    """An :class:`~pcreg.errors.OutputError` when the video file (``frames.path``) is no longer the one run.json names
    (``state``'s ``video_file``) nor it with bytes appended: written again while the run in ``out`` decoded it, so that
    the frames it labelled may be of two videos (a resume would refuse the file; the run that labelled them said
    nothing)."""
    before, now = state.get("video_file"), fingerprint(frames.path)
    if before is None or (before["size"], before["sha256"]) == (now["size"], now["sha256"]) or _appended(before, frames.path, now):
        return
    raise OutputError(f"{frames.path}: written again while the run in {out} labelled it ({before['size']} bytes when "
                      f"it began, {now['size']} now): its labels may be of two videos; use --force to start over")


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
    sha = f.get("sha256") if isinstance(f, dict) else None
    if f is not None and not (counts and isinstance(sha, str) and len(sha) == 64 and set(sha) <= set("0123456789abcdef")):
        return "video_file"
    end = state.get("video_end")
    if end is not None and not (type(end) is int and end >= 1 and f is not None):
        return "video_end"
    return None
