"""A run's ``run.json``: what a run of ``pcreg run`` is (its identity: inputs and options), how far it
has come, its running error against the truth, where its video skips frames by its times (``gaps``,
:mod:`pcreg.runs.gaps`; only when it does), which of its frames decode with errors (``damaged``; only if
any), what else reading its frames met (``notes``: transparent pixels, a turn to interlaced; only if any) and a
video run's file (``video_file``, its fingerprint, and ``video_end`` once its frames were labelled to their end;
:mod:`pcreg.runs.video_file`).
Rewritten atomically after every frame, it is the commit point: a frame counts once run.json counts it.

Two kinds: a run from one label image (``key_frame``, ``done``) and a run from a folder of key frames
(``keys``, ``stretches``, ``cursor``, ``lines``, :mod:`pcreg.pipeline.keys_run`). :func:`open_state` opens
either for a run that writes (resume or start over); :func:`read_state` reads either for a reader
(``pcreg view``, ``pcreg export``); :func:`run_frames` lists what it labelled.
"""

from __future__ import annotations

import math
import os
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Iterator

from ..errors import InputError, OutputError
from ..formats import KeyWrittenTwice, load_json_object, loads_json, resolved
from .files import CONFIDENCE, STATE, STEPS, check_steps_file

if TYPE_CHECKING:
    from ..datasets.sources import Selection

__all__ = ["STATE", "FORMAT", "format_problem", "chosen_selection", "frames_chosen", "unfinished_note", "TRUTH_COUNTS",
           "is_count", "has_counts", "state_problem", "run_identity", "run_inputs", "open_state", "read_state", "run_frames",
           "steps_counted", "steps_counted_now", "named_otherwise", "inputs_placed"]

#: The layout of the run.json this pcreg writes (its ``format``; a run.json without one, from before it was
#: written, has this layout too). A run.json of a later format is refused by name rather than misread.
FORMAT = 1

#: The counters of a run's running error (run.json's ``truth``, and each key-frame stretch's).
TRUTH_COUNTS = ("frames", "wrong", "known", "plain_wrong")


def is_count(value, lo: int = 0) -> bool:
    """Whether ``value`` is an int (not a bool, not a float) of at least ``lo``, as run.json's counts are."""
    return type(value) is int and value >= lo


def has_counts(d, names: tuple[str, ...]) -> bool:
    """Whether ``d`` is a dict whose ``names`` are all counts (:func:`is_count`)."""
    return isinstance(d, dict) and all(is_count(d.get(k)) for k in names)


def _stream_state_problem(state: dict) -> str | None:
    """What in a one-key run's run.json is not as pcreg run writes it (the first field), or None."""
    if not is_count(state.get("done"), 1):
        return "done"
    if not is_count(state.get("fallbacks")):
        return "fallbacks"
    if not isinstance(state.get("key_frame"), str):
        return "key_frame"
    if not isinstance(state.get("key_labels", ""), str):  # runs begun before it was kept have none
        return "key_labels"
    if state.get("key_bytes") is not None and not is_count(state["key_bytes"]):  # a folder's key frame's file size
        return "key_bytes"
    if not _key_contents_ok(state.get("key_contents")):
        return "key_contents"
    scored = isinstance(state.get("run"), dict) and state["run"].get("truth") is not None  # a --truth folder named
    if (state.get("truth") is None) == scored:  # its counts exactly when one is (none: no key, or None)
        return "truth"
    if state.get("truth") is not None and not has_counts(state["truth"], TRUTH_COUNTS):
        return "truth"
    return None


def _key_contents_ok(contents) -> bool:
    """Whether run.json's ``key_contents`` (each key frame's file's modification time and digest, by name; runs begun
    before they were kept have none) is as pcreg run writes it."""
    return contents is None or (isinstance(contents, dict) and all(
        isinstance(e, dict) and type(e.get("mtime_ns")) is int and isinstance(e.get("digest"), str)
        for e in contents.values()))


def _stretch_problem(e, cursor: bool) -> bool:
    """Whether a stretch's entry in run.json (done, or the ``cursor`` under way) is not as pcreg run writes it."""
    if not (isinstance(e, dict) and isinstance(e.get("fingerprint"), str) and is_count(e.get("fallbacks"))
            and (e.get("truth") is None or has_counts(e["truth"], TRUTH_COUNTS)) and (e.get("stop") is None or is_count(e["stop"]))):
        return True
    return cursor and not (isinstance(e.get("phase"), str) and is_count(e.get("steps"))
                           and "next" in e and (e["next"] is None or is_count(e["next"])))


def _keys_state_problem(state: dict) -> str | None:
    """What in a key-frames run's run.json is not as pcreg run writes it (the first field), or None."""
    if not isinstance(state.get("keys"), dict):
        return "keys"
    sizes = state.get("key_bytes")  # a folder's key frames' file sizes (runs begun before they were kept have none)
    if sizes is not None and not (isinstance(sizes, dict) and all(is_count(v) for v in sizes.values())):
        return "key_bytes"
    if not _key_contents_ok(state.get("key_contents")):
        return "key_contents"
    if not isinstance(state.get("stretches"), list) or any(_stretch_problem(e, False) for e in state["stretches"]):
        return "stretches"
    if state.get("cursor") is not None and _stretch_problem(state["cursor"], True):
        return "cursor"
    for name in ("lines", "fallbacks"):
        if not is_count(state.get(name)):
            return name
    if state.get("truth") is not None and not has_counts(state["truth"], TRUTH_COUNTS):
        return "truth"
    return None


def _frame_number(name) -> bool:
    """Whether ``name`` is a video frame's number as run.json names it (``{i:06d}``): ASCII digits, few enough for
    int() (str.isdigit also takes other scripts' digits and superscripts, which int() refuses, and any length)."""
    return isinstance(name, str) and name.isascii() and name.isdigit() and len(name) <= 18


def _gaps_problem(gaps) -> bool:
    """Whether run.json's ``gaps`` (None when there is none) is not as :class:`~pcreg.runs.gaps.GapMarks` writes it."""
    if gaps is None:
        return False
    if not isinstance(gaps, dict) or not isinstance(gaps.get("listed"), dict) or not isinstance(gaps.get("last"), str):
        return True
    counts = [gaps.get("places"), gaps.get("missing"), *gaps["listed"].values()]
    times = gaps.get("times", {})  # runs from before the places' times have none
    if not isinstance(times, dict) or not set(times) <= set(gaps["listed"]) \
            or not all(type(t) in (int, float) and math.isfinite(t) for t in times.values()):
        return True
    return not all(type(c) is int and c >= 1 for c in counts) or not all(map(_frame_number, [gaps["last"], *gaps["listed"]]))


def _damaged_problem(damaged) -> bool:
    """Whether run.json's ``damaged`` (None when there is none) is not as :class:`~pcreg.runs.gaps.GapMarks` writes it."""
    if damaged is None:
        return False
    if not isinstance(damaged, dict) or not isinstance(damaged.get("listed"), list) or not _frame_number(damaged.get("last")):
        return True
    frames = damaged.get("frames")
    return not (type(frames) is int and frames >= max(1, len(damaged["listed"]))) \
        or not all(map(_frame_number, damaged["listed"]))


def _notes_problem(notes) -> bool:
    """Whether run.json's ``notes`` (None when there is none) is not as :class:`~pcreg.runs.gaps.GapMarks` writes it:
    a kind's name to its line, each a text, at least one."""
    if notes is None:
        return False
    return not (isinstance(notes, dict) and notes and all(isinstance(k, str) and k and isinstance(v, str) and v
                                                          for k, v in notes.items()))


def format_problem(state, path: Path) -> str | None:
    """The message when the run.json ``state`` (read from ``path``) is of a later format than this pcreg's
    (:data:`FORMAT`), so that its fields are not read as if this pcreg had written them; None otherwise (a
    ``format`` that is not a count is :func:`state_problem`'s)."""
    from .. import __version__

    found = state.get("format") if isinstance(state, dict) else None
    if not is_count(found, FORMAT + 1):
        return None
    return (f"{path}: written by a later pcreg (run.json format {found}; pcreg {__version__} reads format {FORMAT}): "
            "use that pcreg or a later one")


def state_problem(state) -> str | None:
    """What in a run.json (one key frame's, or a folder of key frames') is not as pcreg run writes it."""
    if not isinstance(state, dict):
        return "its top level"
    if not is_count(state.get("format", FORMAT), 1):
        return "format"
    from .video_file import video_file_problem

    problem = (_keys_state_problem if "stretches" in state else _stream_state_problem)(state)
    records = (("gaps", _gaps_problem), ("damaged", _damaged_problem), ("notes", _notes_problem))
    return problem or next((name for name, bad in records if bad(state.get(name))), None) or video_file_problem(state)


def run_inputs(identity: dict | None) -> tuple[str, ...]:
    """The paths a run reads, from its identity in run.json (``"run"``): its frames (a folder or a video), its key
    labels (a CVAT export among them) and its truth; no output may be written over them, ``--force`` or not."""
    return tuple(v for k, v in (identity or {}).items() if k in ("folder", "video", "labels", "truth")
                 and isinstance(v, str))


def run_identity(frames, source: Path, labels: Path, config, *, mapping: str, truth: str | Path | None,
                 confidence: bool) -> dict:
    """What a run is, as its run.json names it and a resumed run must match: its frames (``source``, a
    folder or a video, and which of them: ``frames.selection``), its ``labels`` (a label image or a folder
    of key frames), how labels are coded (``mapping``), the ``truth`` folder, the propagators' options
    (``config``, a :class:`~pcreg.pipeline.config.PropagatorConfig`), how labels are read from the fused
    log-odds (the trust rule's blur: a run begun when they were read otherwise is not continued),
    ``--confidence``, and the deinterlacing filter of an interlaced video (a run begun when its frames were read
    as decoded is not continued on deinterlaced ones). ``confidence``, the selection and the filter are named only
    when on (runs from before them still resume)."""
    from ..pipeline.trust import STREAM_TRUST

    identity = {frames.kind: str(resolved(source)), "labels": str(resolved(labels)), "mapping": mapping,
                "truth": None if truth is None else str(resolved(truth)), **config.options(),
                "smooth": STREAM_TRUST.smooth}
    if confidence:
        identity["confidence"] = True
    if frames.selection.to_dict() is not None:
        identity["frames"] = frames.selection.to_dict()
    if getattr(frames, "interlaced", False):
        from ..datasets.deinterlace import FILTER

        identity["deinterlaced"] = FILTER[0]
    return identity


def open_state(out: Path, identity: dict | None, *, force: bool, frames=None, also: tuple[str, ...] = ()) -> dict | None:
    """Make ``out`` (a folder) and read the run it holds: its run.json when it is a run of ``identity``
    (the same options and inputs), None when there is none or ``force`` starts over; a run of other
    options, an unreadable run.json, or one whose fields are not as pcreg run writes them
    (:func:`state_problem`) is an :class:`~pcreg.errors.OutputError`, and so, without ``force``, is a folder of no
    run (no run.json, no steps.jsonl: a run writes that first) that holds a label PNG or confidence map the run
    over ``frames`` would write over (a person's own corrected labels, say), a steps.jsonl that is not empty, or a
    file named in ``also`` that the run writes too (suggest.txt with ``--suggest``)."""
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder")
    if (out / "config.json").is_file() and ((out / "results.json").exists() or (out / "units").is_dir()):
        raise OutputError(f"{out}: an evaluation's folder (config.json, results.json or units/): the run's files would "
                          "mix with its report, --force or not; give another --out")
    out.mkdir(parents=True, exist_ok=True)
    state_path = out / STATE
    has_run = os.path.lexists(state_path)  # a folder or a link in its place is no fresh start
    if not has_run:  # a folder of no run: a steps.jsonl there is no run's
        check_steps_file(out / STEPS, force=force)
    begun = (out / STEPS).is_file() and (out / STEPS).stat().st_size == 0  # a run killed at its start: steps.jsonl first, empty
    if not force and frames is not None and not (has_run or begun):
        mine = (out, out / CONFIDENCE) if (identity or {}).get("confidence") else (out,)  # where it writes
        held = next((q for d in mine if d.is_dir() for q in sorted(d.iterdir())
                     if q.suffix.lower() == ".png" and frames.writes(q.stem)), None)
        if held is None and (out / STEPS).is_file():  # not empty (``begun``): a person's, as no run leaves it without run.json
            held = out / STEPS
        held = held or next((out / n for n in also if os.path.lexists(out / n)), None)
        if held is not None:
            raise OutputError(f"{held}: this run would write over it, and {out} holds no run of pcreg's (no {STATE}); "
                              "give another --out, or --force to write over it")
    if force or not has_run:
        return None
    try:
        state = load_json_object(state_path, keys_once=True)  # a key written twice: edited, not pcreg run's
    except ValueError as exc:
        raise OutputError(f"{state_path}: {exc}, not a run's state; use --force to start over") from None
    newer = format_problem(state, state_path)
    if newer is not None:
        raise OutputError(f"{newer}, or --force to start over")
    if not isinstance(state.get("run"), dict):  # no run's identity to tell other options by
        raise OutputError(f"{state_path}: its 'run' is not as pcreg run writes it; use --force to start over")
    before = _moved(_without_unused(state.get("run")), identity, state)
    if before != state.get("run") and before == identity:  # begun when dense and flow took --backend and --init, or moved
        state["run"] = identity
    if state.get("run") != identity and _reaches_further(before, identity):
        state["run"] = identity  # the same run, its --stop later (or gone): it goes on to the frames added
        state.pop("video_end", None)
    if state.get("run") != identity:
        raise OutputError(f"{out} holds a run with other options{_differences(before, identity or {})}; "
                          "use --force to start over or another --out")
    field = state_problem(state)
    if field is not None:
        raise OutputError(f"{state_path}: its {field!r} is not as pcreg run writes it; use --force to start over")
    state["format"] = FORMAT  # the same layout, named from now on
    return state


def _without_unused(run):
    """A run's identity (run.json's ``run``) with the ``backend`` and ``init`` a dense field or DIS's flow never used
    put back to their defaults: a run begun with them, when they were taken, goes on without them."""
    if not (isinstance(run, dict) and (run.get("model") == "dense" or str(run.get("model")).startswith("flow:"))):
        return run
    return {**run, **{k: v for k, v in (("backend", "reference"), ("init", "identity")) if k in run}}


#: The fields of a run's identity that name where its inputs are (:func:`run_inputs`).
_INPUT_PATHS = ("folder", "video", "labels", "truth")


def _moved(before, now: dict | None, state: dict):
    """A run's identity ``before`` (run.json's ``run``) with its inputs' paths as ``now`` names them, where only their
    places differ (a project folder moved or copied, or the frames given through another path): what the inputs hold
    is checked as on any resume, against what ``state`` kept of them (the key labels' digest, or a key-frames run's
    stretches' fingerprints; a folder's key frames' sizes and digests, each labelled frame's in its step; a video's
    fingerprint; each truth map's digest in its step). ``before`` as it is for a run begun before those were kept,
    or an input of another kind (a video for a folder)."""
    if not (isinstance(before, dict) and isinstance(now, dict)):
        return before
    places = {k: now[k] for k in _INPUT_PATHS
              if isinstance(before.get(k), str) and isinstance(now.get(k), str) and before[k] != now[k]}
    return {**before, **places} if places and can_move(state, "folder" if "folder" in now else "video") else before


def can_move(state: dict, kind: str) -> bool:
    """Whether the run of run.json ``state`` kept enough of its inputs (``kind``: its frames a folder or a video) to be
    followed to their new places (:func:`_moved`): what a run begun before they were kept read is not known."""
    labels_kept = "stretches" in state or isinstance(state.get("key_labels"), str)
    return bool(labels_kept and (state.get("key_contents") if kind == "folder" else state.get("video_file")))


@contextmanager
def inputs_placed(out: Path, identity: dict | None, *, force: bool = False) -> Iterator[None]:
    """Around the opening of a run in ``out`` (``identity``: this run's): where its run.json names its inputs in other
    places (taken as moved, :func:`_moved`) and what is found here is refused (a frame, the key labels, the truth not
    what the run read), the refusal says the places then and now first, and another ``--out`` beside ``--force``: the
    inputs here may be another project's, given with this ``--out`` by mistake, whose files the run never read."""
    before = None
    if not force:
        try:
            before = load_json_object(out / STATE).get("run")
        except (OSError, ValueError):
            pass
    then = {k: v for k, v in (before.items() if isinstance(before, dict) else ()) if k in _INPUT_PATHS and isinstance(v, str)}
    now = {k: (identity or {}).get(k) for k in then}
    try:
        yield
    except OutputError as exc:
        moved = [k for k in _INPUT_PATHS if k in then and isinstance(now[k], str) and then[k] != now[k]]
        if not moved:  # the same places, or an input not given now (--truth left out): no other project's inputs
            raise
        said = str(exc).removesuffix("; use --force to start over or another --out").removesuffix("; use --force to start over")
        where = then[moved[0]]
        raise OutputError(f"{out} holds a run over {where}, not over these inputs: give another --out, or --force to "
                          f"start over (what is here is not what it read: {said})") from None


def _reaches_further(before, now: dict | None) -> bool:
    """Whether the run ``now`` (an identity) is the run ``before`` with more of the same frames chosen: the same
    inputs and options, the same ``--start`` and ``--every``, and a ``--stop`` later than the one it had, or none.
    Its frames keep their positions, so what was labelled stands, and a run of hours is labelled a stretch at a
    time."""
    if not (isinstance(before, dict) and isinstance(now, dict)) or {**before, "frames": None} != {**now, "frames": None}:
        return False
    every: dict = {"start": 0, "stop": None, "every": 1}
    then, later = before.get("frames") or every, now.get("frames") or every
    if not (isinstance(then, dict) and isinstance(later, dict)):
        return False
    stop, new_stop = then.get("stop"), later.get("stop")
    return (type(stop) is int and (new_stop is None or (type(new_stop) is int and new_stop > stop))
            and (then.get("start"), then.get("every")) == (later.get("start"), later.get("every")))


def named_otherwise(out: Path, state: dict) -> bool:
    """Whether ``out``'s run.json names the run otherwise than ``state`` does (its inputs found in new places,
    :func:`open_state`), so that it is written again for the review and the export even when nothing is labelled."""
    try:
        return load_json_object(out / STATE).get("run") != state.get("run")
    except ValueError:
        return True


def write_state(out: Path, state: dict) -> None:
    """Commit ``state`` as ``out``'s run.json (atomically: the commit point of a frame)."""
    from ..outputs import atomic_write_json

    atomic_write_json(out / STATE, state)


def no_run(folder: Path, takes: str = "") -> str:
    """What a reader of a run says of a ``folder`` without run.json (``takes``: what the command takes, after a comma):
    a run stopped before it labelled its first frame, where its steps.jsonl is there already and empty (the same command
    starts it), else no run's output."""
    if stopped_before_first_frame(folder):
        return (f"{folder}: a pcreg run stopped there before it labelled its first frame (no {STATE} yet): the same pcreg "
                "run command starts it")
    return f"{folder}: no {STATE}, so not the output of pcreg run{takes}"


def stopped_before_first_frame(folder: Path) -> bool:
    """Whether ``folder`` holds a run stopped before it labelled its first frame: its steps.jsonl there, empty, and no
    run.json (:func:`no_run`)."""
    steps = folder / STEPS
    return not (folder / STATE).is_file() and steps.is_file() and steps.stat().st_size == 0


def read_state(folder: Path) -> dict:
    """The run.json of a finished or stopped run in ``folder``, for a reader: an
    :class:`~pcreg.errors.InputError` naming the file when there is none (not a run's output) or it is not
    one pcreg run wrote."""
    state_path = folder / STATE
    if not state_path.is_file():
        raise InputError(no_run(folder))
    try:
        state = loads_json(state_path.read_text(encoding="utf-8"), keys_once=True)
    except KeyWrittenTwice as exc:  # edited by hand: pcreg run writes each key once
        raise InputError(f"{state_path}: {exc} (not a run.json that pcreg run wrote)") from None
    except (OSError, ValueError, UnicodeDecodeError):
        state = None
    newer = format_problem(state, state_path)
    if newer is not None:
        raise InputError(newer)
    if state_problem(state) is not None or not isinstance(state.get("run"), dict):
        raise InputError(f"{state_path}: unreadable (not a run.json that pcreg run wrote)")
    return state


def _differences(before: object, now: dict) -> str:
    """`` (NAME: A then, B now, ...)``: what differs between a kept run's identity and this one's."""
    from ..validation import short_repr

    if not isinstance(before, dict):
        return ""

    def shown(name: str, d: dict) -> str:
        if name == "frames":  # the frames chosen, as the options choose them
            v = d.get("v")
            v = v if isinstance(v, dict) else {}
            return " ".join(f"--{k} {v[k]}" for k, default in (("start", 0), ("stop", None), ("every", 1))
                            if v.get(k, default) != default) or "every frame"
        v = d.get("v")
        if name == "classes" and isinstance(v, dict) and isinstance(v.get("classes"), list):  # a class table
            return _table_shown(v["classes"])
        if name == "classes.classes" and isinstance(v, list):  # its classes (one table longer than the other)
            return _table_shown(v)
        return short_repr(v) if "v" in d else "not set"

    names = sorted(k for k in set(before) | set(now) if (k in before, before.get(k)) != (k in now, now.get(k)))
    if "frames" in names and _reaches_further({**now, "frames": before.get("frames")}, now):
        names.remove("frames")  # a later --stop alone is taken (:func:`_reaches_further`): not what differs
    said = []
    for k in names[:3]:
        name, then, latest = _first_difference(k, before, now)
        said.append(f"{name}: {shown(name, then)} then, {shown(name, latest)} now")
    return f" ({'; '.join(said)}{'; ...' if len(names) > 3 else ''})" if said else ""


def _table_shown(classes: list) -> str:
    """A kept class table as a person names it: a built-in table's name (the same ids, names and colours), else its
    first class names and count."""
    import json

    from ..classes import TABLES
    from ..classes.files import table_json

    for key, table in TABLES.items():
        if json.loads(table_json(table))["classes"] == classes:
            return f"--classes {key}"
    names = [str(c.get("name")) for c in classes[:3] if isinstance(c, dict)]
    return f"a table of {len(classes)} classes ({', '.join(names)}{', ...' if len(classes) > 3 else ''})"


def _first_difference(name: str, before: dict, now: dict) -> tuple[str, dict, dict]:
    """Where two JSON values ``before[name]`` and ``now[name]`` first differ: the path to the first part
    that differs and is short enough to show whole (``classes.classes[3]``) and its value in each, as
    ``{"v": value}`` (``{}`` where it is not set), so that a difference past what a short repr shows (a
    class renamed in a table) is named."""
    from ..validation import short_repr

    a, b = before.get(name), now.get(name)
    fits = not short_repr(a).endswith("...") and not short_repr(b).endswith("...")
    if name not in before or name not in now or type(a) is not type(b) or fits:
        return name, ({"v": a} if name in before else {}), ({"v": b} if name in now else {})
    if isinstance(a, dict) and isinstance(b, dict):
        k = next(k for k in sorted({*a, *b}, key=str) if (k in a, a.get(k)) != (k in b, b.get(k)))
        inner, then, latest = _first_difference(k, a, b)
        return f"{name}.{inner}", then, latest
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        i = next(i for i, (x, y) in enumerate(zip(a, b)) if x != y)
        inner, then, latest = _first_difference(f"[{i}]", {f"[{i}]": a[i]}, {f"[{i}]": b[i]})
        return f"{name}{inner}", then, latest
    return name, {"v": a}, {"v": b}


def steps_counted(state: dict) -> int:
    """How many lines of steps.jsonl a run's run.json (``state``) counts: a run from a folder of key frames its
    ``lines``, a run from one label image a step for each frame done after its key frame."""
    return int(state["lines"]) if "stretches" in state else int(state["done"]) - 1


def steps_counted_now(folder: Path) -> int:
    """:func:`steps_counted` of the run.json in ``folder`` as it is now, read again (-1 when it cannot be read): a
    reader of a run that ``pcreg run`` is writing finds the steps it committed since it read run.json."""
    try:
        return steps_counted(read_state(folder))
    except (InputError, KeyError, TypeError, ValueError):
        return -1


def run_frames(state: dict, folder: Path) -> tuple[list[str], list[str]]:
    """``(key frames, every labelled frame)`` of a run, by name, in frame order, from its run.json
    (``state``) and the steps of its steps.jsonl in ``folder`` that run.json counts
    (:func:`pcreg.runs.files.counted_steps`): a run from one label image (its key frame, then the
    frames it counted done) or from a folder of key frames (:mod:`pcreg.pipeline.keys_run`: its key
    frames and the steps it counted, in frame order: a folder's name order, a video's frame numbers).
    Raises KeyError, TypeError or ValueError for a state pcreg run did not write, an
    :class:`~pcreg.errors.InputError` naming steps.jsonl for a file pcreg run did not write (a run from one label
    image: a frame named twice among its key frame and steps), ValueError for fewer steps than counted."""
    from .files import counted_steps

    field = state_problem(state)
    if field is not None:
        raise ValueError(f"run.json's {field!r} is not as pcreg run writes it")
    stretches = "stretches" in state
    done = []  # the names alone: an hour's steps whole take about a GB
    counted = steps_counted(state)
    for step in counted_steps(folder, counted, recount=lambda: steps_counted_now(folder)):
        if "name" not in step:
            raise InputError(f"{folder / STEPS}: the step of frame {step['frame']} has no name (not a steps.jsonl "
                             "pcreg run wrote)")
        done.append(str(step["name"]))
    if stretches:
        if len(done) < counted:  # a run appends a step before run.json counts it: never fewer (as pcreg run refuses)
            raise ValueError(f"{len(done)} steps for {counted} finished frames")
        # a video's names are its frames' numbers, of six digits and more from frame 1000000 on: by number
        order = (lambda name: (len(name), name)) if "video" in state["run"] else None
        keys = sorted((str(k) for k in state["keys"]), key=order)
        return keys, sorted(set(keys) | set(done), key=order)
    key, count = str(state["key_frame"]), int(state["done"])
    names = [key] + done
    twice = next((n for i, n in enumerate(names) if n in names[:i]), None) if len(set(names)) < len(names) else None
    if twice is not None:  # a run from one label image labels each frame once, in order
        what = "a step of the key frame" if twice == key else "two steps of the frame"
        raise InputError(f"{folder / STEPS}: {what} {twice} (not a steps.jsonl pcreg run wrote)")
    if len(names) != count:
        raise ValueError(f"{len(names) - 1} steps for {count - 1} labelled frames")
    return [key], names


def chosen_selection(run: dict, state_path) -> Selection:
    """The frames a run's identity (run.json's ``run``, read from ``state_path``) chooses of its source, as
    ``--start``, ``--stop`` and ``--every`` gave them; an :class:`InputError` naming run.json for a choice no run
    writes (not one naming the options, which were not given)."""
    from ..datasets.sources import Selection

    chosen = run.get("frames") or {}
    try:
        return Selection(int(chosen.get("start", 0)), chosen.get("stop"), int(chosen.get("every", 1)))
    except (InputError, ValueError, TypeError, AttributeError):
        raise InputError(f"{state_path}: unreadable (its frames chosen, {str(chosen)[:80]}, are none a run writes)") from None


def frames_chosen(run: dict) -> int | None:
    """How many frames a run's identity (run.json's ``run``) chooses of its frames folder, as it holds them
    now; None for a video (its count is what the container declares, not a fact) or a folder gone."""
    from ..datasets.sources import FolderFrames

    folder = run.get("folder") if isinstance(run, dict) else None
    if not isinstance(folder, str) or not Path(folder).is_dir():
        return None
    try:
        return len(FolderFrames(Path(folder), chosen_selection(run, "run.json")))
    except (InputError, OSError, ValueError, TypeError, AttributeError):
        return None


def unfinished_note(folder: Path, labelled: int, chosen: int | None, *, later: str = "what it labels later is not shown") -> str | None:
    """The note (said on stderr after ``pcreg: note:``) that says a run is unfinished when it labelled fewer of its ``chosen`` frames than there
    are, and whether a command is writing it now (:func:`~pcreg.outputs.writer_of`; then ending in ``later``) or it
    stopped; None when it labelled them all or the count is not known."""
    from ..outputs import writer_of

    if chosen is None:  # a video: how many frames it holds is known once a run decoded it to their end
        unfinished, holds = video_unfinished(folder), f"{folder} holds {labelled} frame(s) of a video"
    elif labelled >= chosen:
        return None
    else:
        unfinished, holds = True, f"{folder} holds {labelled} of the {chosen} frames the run chose"
    writer = writer_of(folder)
    if writer is not None:
        who = f" (pid {writer})" if writer else ""
        return f"{holds}: a pcreg run{who} is writing it now; {later}"
    if unfinished is None and chosen is None:
        return (f"{holds}; its run.json does not say whether the run labelled the video to its end (a run of an earlier "
                "pcreg): the same pcreg run command says \"all frames already done\", or goes on from where it stopped")
    if not unfinished:
        return None
    end = ", which the run did not label to its end" if chosen is None else ""
    return f"{holds}{end}: it is unfinished (the same pcreg run command goes on from where it stopped)"


def video_unfinished(folder: Path) -> bool | None:
    """Whether the run of a video in ``folder`` stopped before the end of its frames, by its run.json (None without
    one): a run from one label image keeps ``video_end`` once decoding found their end
    (:func:`~pcreg.runs.video_file.labelled_to_end`); a run from key frames labels its stretches in order, the last
    one the frames after its last key frame to the video's end (``stop`` None, none when that is the last frame), so
    it is done once that one is and no other is under way (``cursor``); None too for an earlier pcreg's, which kept no end."""
    from .video_file import labelled_to_end

    try:
        state = read_state(folder)
    except InputError:
        return None
    if "done" in state:  # without video_file, which every run since names first, an earlier pcreg's that kept no end
        return None if "video_file" not in state else not labelled_to_end(state)
    ended = any(isinstance(e, dict) and e.get("stop") is None for e in state.get("stretches") or ())
    return state.get("cursor") is not None or not ended
