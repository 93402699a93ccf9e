"""What ``pcreg run`` checks of its ``--record`` file before it labels: a recording of this run cut short (the
run was killed before it closed it), and a recording asked of a run with nothing left to label."""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import OutputError
from .state import STATE

__all__ = ["check_record_path", "check_recording", "name_recording", "nothing_to_record", "run_recording"]


def check_record_path(record) -> None:
    """Refuse a ``--record`` path that rerun cannot take (not a .rrd file's, not UTF-8: a non-ASCII path in the C
    locale without Python's UTF-8 mode, a folder) before the run writes anything, not once the key frame's labels
    are written; a file there already is for :func:`run_recording` to refuse, once the run knows its frames."""
    from ..recording.sink import check_path

    check_path(record, force=True)


def check_recording(out: Path, identity: dict | None, record: Path) -> None:
    """An :class:`OutputError` when ``record`` is the recording of the run in ``out`` (of ``identity``; run.json
    names it) and was cut short (the run was killed before it closed it), saying the two ways on: another
    ``--record`` file resumes the labels (it holds the frames from there on), ``--force`` labels again from the
    key frame so that one recording holds every frame. A choice the person makes: the second costs the time spent.
    So is a ``record`` there already when ``out`` holds no run yet (no run.json): it cannot be this run's recording,
    and is refused before anything is written."""
    from ..formats import load_json_object, resolved
    from ..recording.readback import ended

    if record.is_file() and not (out / STATE).is_file():  # no run whose recording it could be: before anything is written
        raise OutputError(f"{record} exists, and {out} holds no run yet whose recording it could be (another run's, or "
                          "another file); give another --record file, or add --force to write over it")
    try:
        if not record.is_file():
            return
        state = load_json_object(out / STATE)
        if state.get("run") != identity or state.get("recording") != str(resolved(record)) or ended(record):
            return
    except (OSError, ValueError):
        return
    done = state.get("done")
    counted = f" after {done} frames" if isinstance(done, int) else ""
    raise OutputError(f"{record}: the recording of this run, cut short when the run was killed{counted} (it holds "
                      "what was logged up to about a second before: rerun writes a second at a time, so a run killed "
                      "in its first second left it none); to go on from there, give another --record file (it holds "
                      "the frames from there on); to record every frame in this one, add --force (the run starts "
                      "over from the key frame, same labels)")


def run_recording(request, table, earlier=None):
    """The run's recording (:func:`pcreg.recording.recorder.open_recording` of ``request.record``, None for none),
    opened once the run knows it has frames to label: a file there already (the recording of the run as Ctrl-C
    stopped it, which the same command resumes) is refused saying the two ways on, not "exists, use --force"
    alone, which labels every frame again; with ``--force``, moved aside first (``earlier``, the run's
    :class:`~pcreg.runs.earlier.Earlier`), to be put back if bad input stops the run."""
    import contextlib

    from ..errors import OutputError
    from ..recording.null import NULL_RECORDER

    if not request.record:  # rerun not loaded (a third of a second; under a low limit of open files, a panic)
        return contextlib.nullcontext(NULL_RECORDER)
    from ..outputs import check_not_input
    from ..recording.recorder import open_recording

    check_not_input(request.record, (request.frames, request.labels, getattr(request, "truth", None)))
    if not request.force and Path(request.record).is_file():
        raise OutputError(f"{request.record} exists (the recording of this run as it stopped, or another file); to go "
                          "on from there, give another --record file (it holds the frames from there on); to record "
                          "every frame in this one, add --force (the run starts over from the key frame, same labels)")
    if request.force and earlier is not None:
        earlier.set_aside_file(Path(request.record))
    return open_recording(request.record, name=f"run {request.frames}", raw=request.record_raw, force=request.force,
                          classes=table)


def name_recording(state: dict, record, resumed: str | None) -> bool:
    """Name in ``state`` (run.json) the recording ``record`` (a path or None) that the run has opened: ``"recording"``
    the file written now, ``"recordings"`` each file in turn with where it starts (``resumed``: the run resumed,
    said as ``"FRAME on"`` or ``"steps.jsonl line N on"``; None: from the key frames). A resumed run's recording holds only what
    is labelled from there on, which is said on stderr: a recording removed after a stop, written again by the same
    command, would otherwise look like the whole run's. True when ``state`` changed (the caller commits it)."""
    from ..formats import resolved

    if record is None:
        return False
    if resumed is not None:
        sys.stderr.write(f"pcreg: note: {record} records this run from {resumed}: what was labelled before it "
                         "stopped is not in it (--force labels and records every frame)\n")
    path = str(resolved(Path(record)))
    kept = state.get("recordings")
    recordings: list = kept if isinstance(kept, list) else []  # a run.json from before "recordings": none named
    entry = {"file": path, "from": resumed or "the start"}
    if state.get("recording") == path and recordings and recordings[-1] == entry:
        return False
    state["recording"] = path
    state["recordings"] = [*recordings, entry]
    return True


def nothing_to_record(record) -> None:
    """Say, when ``record`` (``--record``, a path or None) names a file that does not exist, that a run with every
    frame labelled writes none: a recording of no frame would look like the run's own, and ``--force`` is the
    way to one."""
    if record is not None and not Path(record).exists():
        sys.stderr.write(f"pcreg: note: every frame is already labelled, so nothing is recorded and {record} is not "
                         "written (--force labels the frames again and records them)\n")
