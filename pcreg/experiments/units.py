"""What the evaluations share: units of work, a per-process data cache, and resumable runs.

- :class:`Unit`: one independent piece of an evaluation (a dataset x increment x backend, a rotated
  frame, a training split), a pure function of its parameters and the evaluation's config;
- :func:`load_cached`: a per-process cache of loaded datasets (units run in worker processes);
- :class:`UnitStore`: finished units kept as JSON files in the output folder, so that a rerun with the
  same configuration skips them (an interrupted run resumes) and a different configuration is refused
  unless ``force``;
- :func:`run_resumable`: run the units not finished yet, in this process or through an executor.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import sys
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from ..recording.null import NULL_RECORDER
from .results import Results
from ..formats import loads_json

if TYPE_CHECKING:
    from .._progress import Tally

# The data sets loaded last, one per process: units sent to worker processes arrive one by one, and a
# worker reads the data once for all those it runs. Loading every unit's data again would cost more
# than the unit (a classification unit takes about 0.5 s, loading two synthetic presets 1.0 s, all six 3.4 s).
_DATA_CACHE: dict = {}


@dataclass(frozen=True)
class Unit:
    """One unit of work of an evaluation.

    key : identifies the result (its file under ``OUT/units/`` is ``KEY.json``).
    dataset : the data set it reads. params : its own parameters as (name, value) pairs, read as
    attributes (``unit.k``, ``unit.backend``). config : the evaluation's frozen config.
    """

    key: str
    dataset: str
    params: tuple[tuple[str, Any], ...] = ()
    config: Any = field(default=None, repr=False, compare=False)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_") or name in ("key", "dataset", "params", "config"):
            raise AttributeError(name)
        for k, v in self.params:
            if k == name:
                return v
        raise AttributeError(f"unit {self.key!r} has no parameter {name!r}")


def load_cached(data: str, *, frames: int | None, size: tuple[int, int] | None, seed: int,
                classes: str | None = None) -> dict:
    """:func:`pcreg.datasets.load_dataset`, cached per process (one data set at a time), under :func:`data_files`' digest
    of its files too: an evaluation run again in the same process (a notebook, a long-lived worker) after a label was
    mended reads the data as it is now, not as it was."""
    key = (data, data_files(data), frames, tuple(size) if size else None, seed, classes)
    if key not in _DATA_CACHE:
        from ..datasets import load_dataset

        _DATA_CACHE.clear()
        _DATA_CACHE[key] = load_dataset(data, n_frames=frames, size=tuple(size) if size else None, seed=seed,
                                        classes=classes)
    return _DATA_CACHE[key]


def say_damage(datasets: dict) -> tuple[str, ...]:
    """Say on stderr which frames of ``datasets`` (``{clip: frames}``, as :func:`load_cached` gives them) decoded
    around damaged data or read with a note (:func:`pcreg.datasets.frame.damage_notes`): scored, their figures are in
    part the decoder's guesses, as ``pcreg register`` says of such an image. Returns the lines, which the results keep
    (:attr:`~pcreg.experiments.results.Results.data_notes`): a report read later says them too."""
    import sys

    from ..datasets.frame import damage_notes

    lines = tuple(damage_notes(datasets))
    for line in lines:
        sys.stderr.write(f"pcreg: note: {line}\n")
    return lines


def angle_key(angle: float) -> str:
    """JSON key of an angle: ``"90"``, ``"2.5"`` (6 significant digits; -0 is ``"0"``)."""
    return f"{angle + 0.0:g}"


def plain_config(config: Any) -> dict:
    """A frozen dataclass config as JSON-ready dict (tuples as lists): its ``to_dict()`` where it has one,
    else all its fields."""
    doc = config.to_dict() if callable(getattr(config, "to_dict", None)) else asdict(config)
    return json.loads(json.dumps(doc, default=str))


#: The file of ``out/units/`` that holds :func:`data_files` of the data the units were made of (a store from
#: before it resumes).
DATA_FILES = "data_files.txt"


def data_files(data) -> str | None:
    """A digest of the names, sizes and modification times of every file under a ``--data`` folder
    (``camvid:PATH`` and the like; None for synthetic data), folders linked into it followed (each once):
    finished units of data that changed since are not results of the data as it is."""
    entries = data_listing(data)
    if entries is None:
        return None
    return _digest(entries)


def _digest(entries: list[str]) -> str:
    import hashlib

    return hashlib.sha256("\n".join(entries).encode("utf-8", "surrogateescape")).hexdigest()[:16]


def data_listing(data) -> list[str] | None:
    """What :func:`data_files` digests: ``NAME\0SIZE\0MTIME_NS`` of every file under the ``--data`` folder, by its
    path in it, in order (None for synthetic data)."""
    import os

    from ..datasets import data_folder

    root = data_folder(data)
    if root is None:
        return None
    entries = []
    seen: set[tuple[int, int]] = set()  # folders walked, by device and inode: a link to a folder above is no loop
    for folder, dirs, names in os.walk(root, followlinks=True):  # a clip linked into the folder is its data too
        try:
            st = os.stat(folder)
        except OSError:
            continue
        if (st.st_dev, st.st_ino) in seen:
            dirs.clear()
            continue
        seen.add((st.st_dev, st.st_ino))
        dirs.sort()
        for name in sorted(names):
            try:
                st = os.stat(os.path.join(folder, name))
            except OSError:
                continue
            entries.append(f"{os.path.relpath(os.path.join(folder, name), root)}\0{st.st_size}\0{st.st_mtime_ns}")
    return entries


def changed_files(before: list[str], now: list[str]) -> str:
    """What differs between two :func:`data_listing` s of one folder, the first file named: ``NAME: added`` (or
    removed, or written again: its size then and now, or its time alone), and how many more."""
    old = {e.split("\0")[0]: e.split("\0")[1:] for e in before}
    new = {e.split("\0")[0]: e.split("\0")[1:] for e in now}
    differ = sorted(n for n in old.keys() | new.keys() if old.get(n) != new.get(n))
    if not differ:
        return "its files changed since"
    first = differ[0]
    if first not in old:
        what = "added"
    elif first not in new:
        what = "removed"
    elif old[first][0] != new[first][0]:
        what = f"written again ({old[first][0]} bytes then, {new[first][0]} now)"
    else:
        what = "written again or touched (its time changed, not its size)"
    shown = first.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")
    more = f", and {len(differ) - 1} more file(s) changed" if len(differ) > 1 else ""
    return f"its files changed since: {shown} {what}{more}"


def config_difference(before: object, now: dict) -> str:
    """`` (NAME: A then, B now; ...)``: the settings of an evaluation's ``config.json`` (``before``) that ``now``'s
    differ in, at most three named (each value shortened), or ``""``."""
    from ..validation import short_repr

    if not isinstance(before, dict):
        return ""
    names = sorted(k for k in before.keys() | now.keys() if before.get(k) != now.get(k))
    said = [f"{k}: {short_repr(before.get(k))} then, {short_repr(now.get(k))} now" for k in names[:3]]
    more = f"; and {len(names) - 3} more" if len(names) > 3 else ""
    return f" ({'; '.join(said)}{more})" if said else ""


class UnitStore:
    """Finished units of one evaluation, one JSON file each under ``out/units/``.

    Opening the store compares ``config`` with ``out/config.json``: the same configuration resumes
    (finished units are loaded, not rerun); a different one raises :class:`~pcreg.errors.OutputError`
    unless ``force``, which clears the old units and report (:func:`~.reports.files.remove_report`), or unless
    no unit finished and no report was written (nothing is lost: it is replaced). ``force`` with the same
    configuration reruns all. Finished units without a readable config.json are refused as well, and so, without
    ``force``, is a folder of no evaluation that holds a file the ``report`` of that name would write over
    (:func:`~.reports.files.in_the_way`: a person's own checks.md, say).
    """

    def __init__(self, out: str | Path, config: dict, *, force: bool, report: str | None = None) -> None:
        from ..outputs import atomic_write_bytes, atomic_write_json
        from ..errors import OutputError
        from .reports.files import in_the_way

        self.out = Path(out)
        self.dir = self.out / "units"
        cfg_path = self.out / "config.json"
        if self.out.exists() and not self.out.is_dir():
            raise OutputError(f"{self.out} exists and is not a folder")
        if (self.out / "run.json").is_file():  # pcreg run's state (pcreg.runs.state.STATE)
            raise OutputError(f"{self.out}: a pcreg run's folder (its run.json): the evaluation's files would mix with "
                              "the run's labels, --force or not; give another --out")
        held = None if force or report is None else in_the_way(self.out, report)
        if held is not None:
            raise OutputError(f"{held}: the report would write over it, and {self.out} holds no evaluation of pcreg's "
                              "(no config.json); give another --out, or --force to write over it")
        old = None
        if cfg_path.is_file():
            try:
                old = loads_json(cfg_path.read_text())
            except (OSError, ValueError):
                old = None
        listing = data_listing(config.get("data"))
        files = None if listing is None else _digest(listing)
        stamp = self.dir / DATA_FILES
        kept = stamp.read_text(encoding="utf-8", errors="surrogateescape").split("\n") if stamp.is_file() else []
        before = kept[0].strip() if kept else None  # then the listing (a store of an earlier pcreg: the digest alone)
        if force:  # start over: the earlier units and report go (its numbers are not this configuration's)
            from .reports.files import remove_report

            if self.dir.is_dir() or self.dir.is_symlink():
                _check_units_folder(self.dir)
                shutil.rmtree(self.dir)
            remove_report(self.out)
        elif old is not None and old != config and self._holds_results():
            raise OutputError(f"{self.out} holds results of a different configuration{config_difference(old, config)} "
                              "(use --force to replace them, or another --out)")
        elif old is None and self._holds_results():
            what = "results.json" if (self.out / "results.json").exists() else "units/ holds finished units"
            raise OutputError(f"{self.out}: {what} without a readable config.json, of a configuration unknown "
                              "(use --force to replace them, or another --out)")
        elif before is not None and listing is not None and before != files and self._holds_results():
            what = changed_files([e for e in kept[1:] if e], listing) if len(kept) > 2 else "its files changed since"
            raise OutputError(f"{self.out} holds results of the data in {config.get('data')} as it was: {what} "
                              "(use --force to replace them, or another --out)")
        atomic_write_json(cfg_path, config)
        if listing is not None:
            atomic_write_bytes(stamp, ("\n".join([str(files), *listing]) + "\n").encode("utf-8", "surrogateescape"))
        self._remove_partial_writes()

    def _remove_partial_writes(self) -> None:
        """Delete the temporary files of writes a run killed mid-write left (``.NAME.*.tmp`` of config.json, of a
        unit's JSON file or of :data:`DATA_FILES`, :func:`pcreg.outputs.atomic_file`); one still being written
        is kept."""
        import os

        from ..outputs import remove_leftovers

        remove_leftovers(self.out, ["config.json"])
        for folder, _, names in os.walk(self.dir):
            if any(n.endswith(".tmp") for n in names):
                remove_leftovers(folder, lambda n: n.endswith(".json") or n == DATA_FILES)

    def _holds_results(self) -> bool:
        """Whether a finished unit or a report is here: a configuration whose run stopped before any (a bad
        option found after it was written) is replaced without ``--force``, nothing being lost."""
        return (self.out / "results.json").exists() or (self.dir.is_dir() and any(self.dir.rglob("*.json")))

    def path(self, key: str) -> Path:
        return unit_path(self.out, key)

    def load(self, key: str) -> dict | None:
        """The finished unit ``key``, or None (a damaged file, or one that holds no JSON object, counts as not
        finished)."""
        p = self.path(key)
        if not p.is_file():
            return None
        try:
            doc = loads_json(p.read_text())
        except (OSError, ValueError):
            return None
        return doc if isinstance(doc, dict) else None

    def save(self, key: str, result: dict) -> None:
        from ..outputs import atomic_write_json

        atomic_write_json(self.path(key), result)


#: Files a file browser leaves in a folder it showed (Windows'), besides hidden ones (macOS's ``.DS_Store``).
_BROWSERS_FILES = frozenset({"Thumbs.db", "desktop.ini"})


def _check_units_folder(folder: Path) -> None:
    """An :class:`~pcreg.errors.OutputError` unless ``folder`` (``OUT/units``, which ``--force`` removes) holds only what
    an evaluation writes there (units' JSON files in folders, :data:`DATA_FILES` and killed writes' ``.tmp`` files) and
    what a file browser leaves (hidden files, such as ``.DS_Store``; ``Thumbs.db``, ``desktop.ini``). A person's own
    files of other kinds in a folder of that name (a CSV of measurements) are not removed with it; their JSON files
    cannot be told from units."""
    import os

    from ..errors import OutputError

    if folder.is_symlink():
        raise OutputError(f"{folder}: a link, not the folder an evaluation writes its units in; --force removes "
                          "only that: give another --out, or remove the link")
    for root, dirs, names in os.walk(folder):
        for name in sorted(names) + sorted(d for d in dirs if os.path.islink(os.path.join(root, d))):
            path = Path(root) / name
            if path.is_symlink() or not (name.endswith((".json", ".tmp")) or name in _BROWSERS_FILES
                                         or name.startswith(".") or name == DATA_FILES):
                raise OutputError(f"{path}: not a file an evaluation writes, in the folder of its units that --force "
                                  "removes; move it out of the folder, or give another --out")


def unit_path(out: str | Path, key: str) -> Path:
    """The file of ``out/units/`` that keeps the finished unit ``key``: ``KEY.json``, or, where that is longer than a
    file's name may be (a clip's folder named near the 255 bytes a name holds), the key's first bytes and a digest of
    it all (a key's results name it inside)."""
    *folders, last = f"{key}.json".split("/")
    return Path(out, "units", *map(_fitted, folders), _fitted(last, ".json"))


#: The most bytes a file's name may hold on Linux's, macOS's and Windows' file systems (a temporary name written
#: first is cut to fit by :func:`pcreg.outputs.atomic_write_bytes`).
_NAME_MAX = 255


def _fitted(name: str, suffix: str = "") -> str:
    """``name`` (ending in ``suffix``), or, past :data:`_NAME_MAX` bytes, its first characters that fit with a digest of
    it all (the name kept before wherever that fits, so a resumed evaluation finds its units)."""
    raw = name.encode("utf-8", "surrogateescape")
    if len(raw) <= _NAME_MAX:
        return name
    digest = hashlib.sha256(raw).hexdigest()[:16]
    head = raw[:_NAME_MAX - len(suffix.encode()) - 17].decode("utf-8", "ignore")  # no character cut in two
    return f"{head}-{digest}{suffix}"


def discard_units(out: str | Path, units: list) -> None:
    """Delete the kept results of ``units`` from ``out/units/``: those of a run refused as bad input for what they hold
    (no number), which would make the corrected command's folder one of "a different configuration"."""
    for u in units:
        unit_path(out, u.key).unlink(missing_ok=True)


def holds(result: dict, unit: Unit, keys: tuple[str, ...], *, same: tuple[str, ...] = ()) -> bool:
    """Whether a kept unit's ``result`` holds each of ``keys`` and names ``unit``: each of ``same`` (``"dataset"``,
    ``"backend"``, a parameter) equal to the unit's. A ``kept`` test of :func:`run_resumable`."""
    return all(k in result for k in keys) and all(k in result and result[k] == getattr(unit, k) for k in same)


def run_resumable(units: list, run_unit, *, store: "UnitStore | None", cfg_dict: dict, recorder=NULL_RECORDER,
                  executor=None, desc: "str | Tally" = "", show_progress: bool | None = None,
                  kept: Callable[[Unit, dict], bool] | None = None) -> tuple[dict, int]:
    """Run the units not finished yet (``store`` keeps each result as it lands), in this process when
    recording (one recorder, frames in order), else through ``executor``. ``kept(unit, result)``: whether a
    kept result is one this version's summary can read (one an earlier pcreg wrote without a section this one
    has, or a file edited, is run again rather than read without it). ``desc``: the bar's name, or a
    :class:`~pcreg._progress.Tally` of what it counts (:func:`~pcreg._runner.run_units`).

    Returns the results by unit key (finished and new) and how many came from an earlier run. A finished
    unit's ``recording_frames`` (where it lies on an earlier run's recording) is dropped: this run's
    recording, if any, holds only the units it runs.
    """
    from functools import partial

    from .._runner import InlineExecutor, run_units
    from ..validation import check_units

    check_units(len(units), "evaluation units")
    done: dict[str, dict] = {}
    todo = []
    for u in units:
        prev = store.load(u.key) if store is not None else None
        if prev is not None and (kept is None or kept(u, prev)):
            prev.pop("recording_frames", None)
            done[u.key] = prev
        else:
            todo.append(u)

    def keep(unit, result: dict) -> None:
        done[unit.key] = result
        recorder.flush()  # a unit counts as done with its frames in the recording, not a second later
        if store is not None:
            store.save(unit.key, result)

    if recorder.enabled and len(todo) < len(units):
        _say_resumed_recording(recorder, ran=len(todo), finished=len(units) - len(todo))
    if recorder.enabled and todo:  # a recording is written by this process, its frames in order
        recorder.log_config(cfg_dict)
        run_units(partial(run_unit, recorder=recorder, frame_counter=[0]), todo, executor=InlineExecutor(), desc=desc,
                  on_result=keep, show_progress=show_progress)
    else:
        if getattr(executor, "remote", False):
            todo = [replace(u, config=for_workers(u.config)) for u in todo]
        run_units(run_unit, todo, executor=executor or InlineExecutor(), desc=desc, on_result=keep,
                  show_progress=show_progress)
    return done, len(units) - len(todo)


def _say_resumed_recording(recorder, *, ran: int, finished: int) -> None:
    """Say on stderr what the recording of a resumed evaluation holds: the ``ran`` units this run runs, not the
    ``finished`` ones an earlier run kept. With none to run it is not written (:meth:`Recorder.discard`): a
    recording of no unit would look like the evaluation's own, as :func:`pcreg.runs.records.nothing_to_record` says
    of ``pcreg run``."""
    again = "--force runs every unit again and records them"
    if ran:
        sys.stderr.write(f"pcreg: note: {recorder.path} records the {ran} unit(s) this run runs: the {finished} an "
                         f"earlier run finished are not in it ({again})\n")
        return
    sys.stderr.write(f"pcreg: note: every unit is already done, so nothing is recorded and {recorder.path} is not "
                     f"written ({again})\n")
    recorder.discard()


def for_workers(config: Any) -> Any:
    """``config`` as a cluster's workers read it: its ``--data`` path and ``--classes`` file made absolute (the
    parent checked them from its working folder; a worker read the same relative path from its own, where it named
    no files, or other files, scored under the right names)."""
    import os

    from ..classes.table import TABLES
    from ..datasets import absolute_data

    changes: dict[str, Any] = {}
    if isinstance(getattr(config, "data", None), str):
        changes["data"] = absolute_data(config.data)
    classes = getattr(config, "classes", None)
    if isinstance(classes, str) and classes.strip() and classes not in TABLES:
        changes["classes"] = os.path.abspath(os.path.expanduser(classes))
    return replace(config, **changes) if changes else config


def evaluate_units(units: list, run_unit, config: Any, *, summarise, out: str | Path | None = None,
                   force: bool = False, executor=None, recorder=NULL_RECORDER, desc: "str | Tally" = "",
                   show_progress: bool | None = None, kept: Callable[[Unit, dict], bool] | None = None,
                   data_notes: tuple[str, ...] = ()) -> Results:
    """The body every resumable evaluation shares: run the units not finished in ``out/units`` (all of
    them without ``out``; ``kept``, ``desc``: as :func:`run_resumable`), summarise their results in order (``summarise(config, results)``), and add
    the presets' real counterparts, the number of resumed units, the wall time and ``data_notes`` (:func:`say_damage`'s)."""
    import time

    from ..datasets import PRESETS

    t0 = time.perf_counter()
    cfg_dict = plain_config(config)
    store = UnitStore(out, cfg_dict, force=force, report=getattr(config, "report", None)) if out is not None else None
    done, resumed = run_resumable(units, run_unit, store=store, cfg_dict=cfg_dict, recorder=recorder,
                                  executor=executor, desc=desc, show_progress=show_progress, kept=kept)
    results = summarise(config, [done[u.key] for u in units])
    for name, tables in results.datasets.items():
        if name in PRESETS:
            tables["mirrors"] = PRESETS[name].mirrors
    return replace(results, resumed_units=resumed, seconds=time.perf_counter() - t0, data_notes=tuple(data_notes) or None)
