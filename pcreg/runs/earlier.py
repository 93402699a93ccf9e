"""The earlier run a run started over (``pcreg run --force``) replaces, kept until the new run is past bad input.

A run started over in a folder that holds an earlier run moves that run's files aside as it begins (into
``OUT/.earlier-run/``, renames within the folder) instead of deleting them. Stopped by bad input or an output it
cannot write (an :class:`~pcreg.errors.InputError` or :class:`~pcreg.errors.OutputError`, exit 2: a frame
partway that does not read, or is of another size), the new run's files are taken away again and the earlier
run's put back as they were: bad input loses nothing. Finished, the earlier run is deleted. Interrupted (or
stopped by a bug), both stay: the new run resumes (the same command without ``--force``), and the earlier one
is deleted when a run in the folder finishes, or when another run starts over there (a run killed after it
started over left it: what the folder holds then is the run started over). The ``--record`` file a run started
over writes again is kept so too, beside itself (``.NAME.earlier``): put back with the run, deleted when the new
run finishes or is interrupted (the new recording is the one a resumed run goes on from).
"""

from __future__ import annotations

import os
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterable, Iterator

from ..errors import InputError, OutputError

__all__ = ["EARLIER", "Earlier"]

#: The folder in ``OUT`` that holds the earlier run's files while a run started over has not finished.
EARLIER = ".earlier-run"


class Earlier:
    """The earlier run in ``out`` that a run started over replaces (see the module's docstring)."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.folder = out / EARLIER
        self.moved: list[Path] = []  # the paths in ``out`` moved aside by this process, to put back
        self.beside: list[tuple[Path, Path]] = []  # (a file elsewhere, where it was moved aside) by this process

    def set_aside(self, paths: Iterable[Path]) -> None:
        """Move each of ``paths`` (files or folders in ``out``; those that are not there skipped) aside, into
        :attr:`folder` under its name. A folder left by a run killed after it started over is deleted first:
        what ``out`` holds now is the run started over then."""
        if not self.moved:
            shutil.rmtree(self.folder, ignore_errors=True)
        for path in paths:
            if not os.path.lexists(path):
                continue
            try:
                self.folder.mkdir(exist_ok=True)
                os.replace(path, self.folder / path.name)
            except OSError as exc:
                raise OutputError(f"cannot move {path} aside into {self.folder} to start over: "
                                  f"{exc.strerror or exc}") from None
            self.moved.append(path)

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

    def put_back(self, written: Iterable[Path]) -> None:
        """Take the files and folders the new run has ``written`` away and put the earlier run's back where they were."""
        for path in written:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
        for path in self.moved:
            os.replace(self.folder / path.name, path)
        self.moved = []
        self.drop()

    def drop(self) -> None:
        """Delete the earlier run's files (and a recording set aside)."""
        shutil.rmtree(self.folder, ignore_errors=True)
        self._drop_beside()

    def _drop_beside(self) -> None:
        for _, aside in self.beside:
            aside.unlink(missing_ok=True)
        self.beside = []

    @contextmanager
    def kept(self, written) -> Iterator[None]:
        """Around a run's labelling: put the earlier run back when bad input or an output that cannot be written stops
        the new one (``written()``: the paths the new run wrote), delete it when the run finishes."""
        try:
            yield
        except (InputError, OutputError):
            for path, aside in self.beside:
                os.replace(aside, path)
            self.beside = []
            if self.moved:
                self.put_back(written())
            raise
        except BaseException:
            self._drop_beside()
            raise
        self.drop()
