"""How much memory ``pcreg run`` needs for its frames' size and classes, and a note before it starts when the
machine has less to give: a process that asks for more than there is is killed by the system without a word
(the run resumes, but the user learns nothing of why).

The step keeps maps of the working size, several of them one value a class (the scores, the carried priors,
their blur), so its memory grows with the pixels times the classes. Measured with ``/usr/bin/time -f %M`` on
``pcreg run`` over eight CamVid frames brought to 1280x720 (resident peak: 603 MiB with two classes, 1031 MiB with
eleven, 620 MiB with eleven at ``--scale 0.5``), and on the step alone at 640x480, 1280x720 and 1920x1080
(docs/operations.md, "Memory")."""

from __future__ import annotations

from pathlib import Path

__all__ = ["BASE_BYTES", "FRAME_BYTES", "WORK_BYTES", "CLASS_BYTES", "CGROUP_FILES", "run_bytes", "available_bytes",
           "cgroup_bytes", "memory_note", "key_classes", "run_note"]

#: What the process holds before the first frame: the interpreter, the libraries and the compiled kernels.
BASE_BYTES = 400 * 2**20
#: Bytes a pixel of the frames' own size: the frame decoded, the next one read ahead, the labels and the
#: confidence written behind.
FRAME_BYTES = 100
#: Bytes a pixel of the working size besides the classes' maps: the registration's pyramids and field, DIS.
WORK_BYTES = 30
#: Bytes a pixel of the working size for each class: the class scores, the carried priors, the fused scores and
#: their blur.
CLASS_BYTES = 54
#: Where a container's memory limit is read, as the container sees its own cgroup: (limit, use, statistics) of
#: cgroup v2, then of v1.
CGROUP_FILES = (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current", "/sys/fs/cgroup/memory.stat", "inactive_file"),
                ("/sys/fs/cgroup/memory/memory.limit_in_bytes", "/sys/fs/cgroup/memory/memory.usage_in_bytes",
                 "/sys/fs/cgroup/memory/memory.stat", "total_inactive_file"))
#: The smaller working sizes the note proposes, in order.
SCALES = (0.75, 0.5, 0.25)


def run_bytes(width: int, height: int, classes: int, scale: float = 1.0) -> int:
    """The resident memory (bytes) a run over frames of ``width`` x ``height`` with ``classes`` classes (two for
    ground and obstacle) at ``scale`` is expected to reach."""
    work = max(1, round(width * scale)) * max(1, round(height * scale))
    return int(BASE_BYTES + FRAME_BYTES * width * height + work * (WORK_BYTES + CLASS_BYTES * max(2, classes)))


def available_bytes(meminfo: Path = Path("/proc/meminfo"), cgroups=CGROUP_FILES) -> int | None:
    """The memory the system can give without swapping (``MemAvailable``), or what a container's memory limit
    leaves (:func:`cgroup_bytes`) where that is less; None where neither says."""
    known = [b for b in (_meminfo_bytes(meminfo), cgroup_bytes(cgroups)) if b is not None]
    return min(known) if known else None


def _meminfo_bytes(meminfo: Path) -> int | None:
    try:
        for line in meminfo.read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def cgroup_bytes(files=CGROUP_FILES) -> int | None:
    """What the memory limit of the cgroup this process sees as its own (a container's: ``docker run --memory``)
    leaves: the limit less the use, the use without the page cache the kernel reclaims first (``inactive_file``,
    as ``docker stats`` counts it); None where no limit is set or none can be read. Inside a container
    ``MemAvailable`` is the host's, and a process over the limit is killed without a word."""
    for limit_file, use_file, stat_file, inactive in files:
        try:
            limit, used = Path(limit_file).read_text().strip(), int(Path(use_file).read_text().strip())
        except (OSError, ValueError):
            continue
        if limit == "max" or not limit.isdigit() or int(limit) >= 2**62:  # no limit (v1 writes one near 2**63)
            return None
        cache = 0
        try:
            for line in Path(stat_file).read_text().splitlines():
                name, _, value = line.partition(" ")
                if name == inactive:
                    cache = int(value)
        except (OSError, ValueError):
            pass
        return max(0, int(limit) - max(0, used - cache))
    return None


def memory_note(width: int, height: int, classes: int, scale: float, available: int | None) -> str | None:
    """A one-line note when a run is expected to need more than ``available`` bytes (None: unknown, no note),
    naming the largest of :data:`SCALES` below ``scale`` that fits; None when it fits."""
    need = run_bytes(width, height, classes, scale)
    if available is None or need <= available:
        return None
    gib = 2.0**30
    said = (f"a run over {width}x{height} frames with {max(2, classes)} classes"
            f"{f' at --scale {scale:g}' if scale != 1 else ''} is expected to need about {need / gib:.1f} GiB, and "
            f"{available / gib:.1f} GiB is available: the system may stop it without a message (it resumes)")
    fits = next((s for s in SCALES if s < scale and run_bytes(width, height, classes, s) <= available), None)
    if fits is None:
        return said + "; free memory or give smaller frames"
    return said + f"; --scale {fits:g} needs about {run_bytes(width, height, classes, fits) / gib:.1f} GiB"


def key_classes(keys, table) -> int:
    """How many known classes of ``table`` the key labels ``keys`` ((H, W) class ids, one per key frame) show:
    the step keeps its maps for the classes its classifier learned from them, not for every class of the table
    (at 1280x720 a table of 254 classes whose key frame shows eleven reached 1019 MiB, camvid11's eleven 969)."""
    import numpy as np

    shown = np.zeros(256, bool)
    for labels in keys:
        shown[np.unique(np.asarray(labels))] = True
    return sum(1 for k in table.known_ids if shown[k])


def run_note(keys, table, scale: float, available: int | None) -> str | None:
    """:func:`memory_note` for a run from the key labels ``keys`` (of the frames' size) in ``table``, counting
    the classes they show (:func:`key_classes`)."""
    keys = list(keys)
    h, w = keys[0].shape[:2]
    return memory_note(w, h, key_classes(keys, table), scale, available)
