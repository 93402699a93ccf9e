"""The earlier run a run started over (``pcreg run --force``) replaces, kept until the new run has finished.

A run started over in a folder that holds an earlier run moves that run's files aside as it begins (into
``OUT/.earlier-run/``, renames within the folder, run.json last) instead of deleting them, and its ``--record``
file beside itself (``.NAME.earlier``). What becomes of them:

- the new run finishes: they are deleted;
- it is interrupted (Ctrl-C, SIGTERM): the new run stays, to resume (the same command without ``--force``), and
  the earlier run stays aside until a run in the folder finishes (the recording set aside is deleted: the new one
  is what a resumed run goes on from);
- anything else stops it (bad input, exit 2: a frame partway that does not read, or is of another size; an output
  that cannot be written, memory run out, a bug): the new run's files are taken away and the earlier run's put
  back as they were, its recording too, and the error says so. Bad input loses nothing.

A run killed while it moved the files aside left some in the folder (no run.json among them): the next run
started over there moves the rest beside them. A run killed later left a whole earlier run there (its run.json
moved last): the next run started over deletes it, since what ``OUT`` holds then is the run started over.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterable, Iterator

from ..errors import DatasetError, InputError, OutputError
from .files import EARLIER, RUN_FILES, STATE

__all__ = ["EARLIER", "Earlier"]


class Earlier:
    """The earlier run in ``out`` that a run started over replaces (see the module's docstring)."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.folder = out / EARLIER
        self.aside = False  # whether this process moved the run in ``out`` aside (its files are in :attr:`folder`)
        self.beside: list[tuple[Path, Path]] = []  # (a file elsewhere, where this process moved it aside)
        self.present: set[str] = set()  # the names in ``out`` once the earlier run was moved aside

    def set_aside(self, paths: Iterable[Path]) -> None:
        """Move each of ``paths`` (files or folders in ``out``, run.json last; those not there skipped) into
        :attr:`folder` under its name; a move that fails puts the ones before it back and is an :class:`OutputError`."""
        if os.path.islink(self.folder) or (os.path.lexists(self.folder) and not self.folder.is_dir()):
            raise OutputError(f"{self.folder}: not the folder pcreg run keeps an earlier run in while a run started "
                              "over there has not finished; remove it, or choose another --out")
        if (self.folder / STATE).exists():  # a whole earlier run, left by a run started over and killed
            shutil.rmtree(self.folder)
        moved: list[Path] = []
        for path in paths:
            if not os.path.lexists(path):
                continue
            try:
                self.folder.mkdir(exist_ok=True)
                os.replace(path, self.folder / path.name)
            except BaseException as exc:  # a file that will not move, or Ctrl-C: the ones moved go back
                for done in reversed(moved):
                    os.replace(self.folder / done.name, done)
                with contextlib.suppress(OSError):
                    self.folder.rmdir()  # made here, or left by a run killed while it moved: only when empty
                if not isinstance(exc, OSError):
                    raise
                raise OutputError(f"cannot move {path} aside into {self.folder} to start over: "
                                  f"{exc.strerror or exc}; the earlier run is left as it was") from None
            moved.append(path)
        self.aside = self.folder.is_dir()
        self.present = set(os.listdir(self.out))  # what the new run begins beside: anything of a run's beyond it is its

    def set_aside_file(self, path: Path) -> None:
        """Move the file ``path`` (a recording the run writes again; not there: nothing) aside, beside itself."""
        if not path.is_file():
            return
        aside = path.with_name(f".{path.name}.earlier")
        try:
            os.replace(path, aside)
        except OSError as exc:
            raise OutputError(f"cannot move {path} aside to {aside} to start over: {exc.strerror or exc}") from None
        self.beside.append((path, aside))

    def put_back(self, written: Iterable[Path]) -> list[str]:
        """Put the recording set aside back, and, when the run in ``out`` was set aside, take the files and folders the
        new run has ``written`` away and put the earlier run's back; what could not be done, said (none: [])."""
        failed: list[str] = []
        for path, aside in self.beside:
            try:
                os.replace(aside, path)
            except OSError as exc:
                failed.append(f"{aside} ({exc.strerror or exc})")
        self.beside = []
        if not self.aside:
            return failed
        # what the new run wrote: what its records name, and any file of a run's that was not there when it began (a
        # frame's label PNG written before its step line, when the run stopped between the two)
        extra = [self.out / n for n in os.listdir(self.out) if n not in self.present and n != EARLIER
                 and (n in RUN_FILES or n.endswith((".png", ".tmp")))]
        for path in dict.fromkeys([*written, *extra]):
            try:
                if path.is_dir() and not path.is_symlink():
                    shutil.rmtree(path)
                else:
                    path.unlink(missing_ok=True)
            except OSError as exc:
                failed.append(f"{path} ({exc.strerror or exc})")
        for name in sorted(os.listdir(self.folder)):
            try:
                os.replace(self.folder / name, self.out / name)
            except OSError as exc:
                failed.append(f"{self.folder / name} ({exc.strerror or exc})")
        if not failed:
            self.drop()
        self.aside = False
        return failed

    def drop(self) -> None:
        """Delete the earlier run's files (and a recording set aside)."""
        shutil.rmtree(self.folder, ignore_errors=True)
        self._drop_beside()

    def _drop_beside(self) -> None:
        for _, aside in self.beside:
            aside.unlink(missing_ok=True)
        self.beside = []

    @contextmanager
    def kept(self, written: Callable[[], list[Path]]) -> Iterator[None]:
        """Around a run's labelling: the earlier run deleted when it finishes, kept aside when it is interrupted, put
        back when anything else stops it (``written()``: the paths the new run wrote; see the module's docstring)."""
        from .._runner import interrupted

        try:
            yield
        except BaseException as exc:
            if isinstance(exc, KeyboardInterrupt) or interrupted():
                self._drop_beside()
                raise
            if not (self.aside or self.beside):
                raise
            records, was_aside = [str(path) for path, _ in self.beside], self.aside
            try:
                written_now = written()
            except Exception:  # noqa: BLE001 - the run's own records unreadable: what was not there before goes
                written_now = []
            failed = self.put_back(written_now)
            if not isinstance(exc, (InputError, OutputError, DatasetError)):
                raise
            if failed:
                said = f"; the earlier run could not be put back wholly: {', '.join(failed[:3])} left as they are"
            elif was_aside:
                said = f"; {self.out} holds the earlier run again, as it was"
            else:
                said = f"; {', '.join(records)} holds the earlier recording again, as it was"
            exc.args = (f"{_without_going_on(exc)}{said}", *exc.args[1:])
            raise
        self.drop()


def _without_going_on(exc: BaseException) -> str:
    """``exc``'s words without the note that the frames labelled before a bad frame are kept (a run started over
    keeps the earlier run's instead)."""
    from ..datasets.folder_view import GOES_ON

    return str(exc).replace(GOES_ON, "")
