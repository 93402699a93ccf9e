"""How much disk a run from several key frames needs under ``OUT/.keys/`` (what a stretch's forward pass keeps
for its backward pass, :mod:`pcreg.runs.kept`, removed when the stretch is done), and a note before the run
starts when ``OUT``'s filesystem has less free: a disk that fills stops the run (it resumes once there is room,
losing nothing), but late, after hours of labelling. The same figures decide whether the run keeps them
compressed at all (:func:`compress_kept`): compressing costs time, so it is done only where the disk needs it.

The stretch that needs the most is the longest: between two key frames each frame's prior term (at the working
size), and for a video each decoded frame (at the frames' size) from the stretch's first frame to its later key
frame. What a frame takes is the array's bytes times the share the compression leaves, measured on CamVid
frames at 640x480 (the larger share of 640x480 and 1920x1080, rounded up; docs/benchmarks.md, "What a stretch
keeps on disk"): it depends on the pictures, so the figure is an expectation, not a bound. Uncompressed
(``compressed=False``) the share is 1: the arrays' bytes.
"""

from __future__ import annotations

import shutil
from pathlib import Path

__all__ = ["FRAME_SHARE", "PRIOR_SHARE", "CLASSES_SHARE", "frame_bytes", "prior_bytes", "stretch_bytes",
           "free_bytes", "compress_kept", "disk_note", "choose_kept"]

#: The share of a video frame's bytes (3 a pixel) kept: 446 kB of 922 kB at 640x480, 1.90 MB of 6.22 MB at
#: 1920x1080.
FRAME_SHARE = 0.5
#: The share of a prior term's bytes kept with two classes (2 a pixel): 288 kB of 615 kB, 1.47 MB of 4.15 MB.
PRIOR_SHARE = 0.5
#: The same with more classes (2 a pixel for each class but one, and 2 for the weight): with ``camvid11``
#: 1.47 MB of 6.14 MB, 6.42 MB of 41.5 MB.
CLASSES_SHARE = 0.25


def frame_bytes(width: int, height: int, *, compressed: bool = True) -> float:
    """The bytes a video's frame of ``width`` x ``height`` is expected to take kept, ``compressed`` or not."""
    return (FRAME_SHARE if compressed else 1.0) * 3 * width * height


def prior_bytes(width: int, height: int, classes: int, *, compressed: bool = True) -> float:
    """The bytes a prior term of the working size ``width`` x ``height`` with ``classes`` classes is expected to
    take kept, ``compressed`` or not."""
    if classes <= 2:
        return (PRIOR_SHARE if compressed else 1.0) * 2 * width * height
    return (CLASSES_SHARE if compressed else 1.0) * 2 * classes * width * height


def stretch_bytes(first: int | None, last: int | None, *, video: bool, frame: float, prior: float) -> float:
    """The bytes a stretch from key frame ``first`` (None: from the first frame) to ``last`` (None: to the end)
    keeps at most: ``prior`` bytes for each frame between two key frames, and for a ``video`` ``frame`` bytes
    for each frame from its first (``first`` itself, when there is one) to ``last``."""
    if last is None:
        return 0.0  # forwards from the last key frame: nothing kept
    kept = 0.0
    if first is not None:
        kept += prior * max(0, last - first - 1)
    if video:
        kept += frame * (last - (0 if first is None else first) + 1)
    return kept


def free_bytes(path: Path) -> int | None:
    """The bytes free to this user on the filesystem of ``path`` (or of its nearest folder that exists), or
    None where the system does not say."""
    path = Path(path).absolute()
    while not path.exists() and path.parent != path:
        path = path.parent
    try:
        return shutil.disk_usage(path).free
    except OSError:
        return None


def compress_kept(raw: float, free: int | None) -> bool:
    """Whether a run whose stretches are expected to keep at most ``raw`` bytes uncompressed keeps them
    compressed, ``free`` bytes being free (None: unknown): only when ``raw`` is more than half of ``free``, or
    ``free`` is unknown. Compressing takes time (docs/benchmarks.md, "What a stretch keeps on disk"); the half
    leaves room for the run's outputs and for what else writes to that disk while it runs."""
    return free is None or raw > free / 2


def _size(n: float) -> str:
    """``n`` bytes as the note says them: ``5.0 GiB``, ``3.2 MiB``, ``64 kB`` (in GiB alone, a disk with 40 MB free
    and a stretch that needs 60 both read ``0.0 GiB``)."""
    from ..formats import _bytes

    return f"{n / 2**30:.1f} GiB" if n >= 2**30 else _bytes(n)


def disk_note(need: float, free: int | None, out: Path) -> str | None:
    """A one-line note when a run is expected to need ``need`` bytes under ``out``/.keys/ and ``free`` (None:
    unknown, no note) are free there; None when it fits."""
    if free is None or need <= free:
        return None
    return (f"the longest stretch between key frames is expected to keep about {_size(need)} under "
            f"{Path(out) / '.keys'} while it is labelled, and {_size(free)} is free there: the run would "
            "stop when the disk fills (it resumes); free space, add a key frame within the stretch, or give "
            "--out on a larger disk")


def choose_kept(job, out: Path) -> None:
    """Whether ``job`` (a :class:`~pcreg.pipeline.keys_run.KeyRun`) keeps its stretches' files compressed, for
    the whole run: only when, uncompressed, they would take more than half of what is free under ``out``
    (:func:`~pcreg.runs.disk.compress_kept`); and a note on stderr before the first frame when even compressed
    they are expected to take more than is free (:func:`~pcreg.runs.disk.disk_note`)."""
    import sys

    free = free_bytes(out)
    job.compress = compress_kept(job.kept_bytes(compressed=False), free)
    note = disk_note(job.kept_bytes(), free, out) if job.compress else None
    if note:
        sys.stderr.write(f"pcreg: note: {note}\n")
