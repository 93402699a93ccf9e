"""Atomic output: every file pcreg writes appears whole or not at all."""

from __future__ import annotations

import csv
import io
import json
import os
import re
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, BinaryIO, Callable, Iterable, Iterator, Sequence

import numpy as np

from .errors import OutputError


_UMASK = os.umask(0)
os.umask(_UMASK)


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, (set, frozenset)):
        return sorted(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def to_json(obj: Any, *, strict: bool = False) -> str:
    """JSON text with numpy values converted. NaN/inf are written as Python's ``NaN`` (read back by
    :func:`json.loads`), or as ``null`` with ``strict`` (valid JSON for any reader)."""
    if strict:
        return json.dumps(finite(obj), indent=2, default=_jsonable, sort_keys=False, allow_nan=False)
    return json.dumps(obj, indent=2, default=_jsonable, sort_keys=False)


def finite(obj: Any) -> Any:
    """``obj`` ready for strict JSON: float NaN/inf (Python or numpy) replaced by None, numpy numbers and arrays
    made Python's, containers rebuilt."""
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, (np.integer, np.bool_)):
        return obj.item()
    if isinstance(obj, dict):
        return {k: finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return finite(obj.tolist())
    return obj


#: The longest file name a temporary file's is made from (bytes): mkstemp adds 14, and file systems take 255.
SHORT_NAME = 200


def _short(name: str) -> str:
    """``name``, or its stem cut to fit :data:`SHORT_NAME` bytes with its suffix kept (a temporary file of a
    frame's label PNG is still ``.NAME.png.*.tmp``, which a resumed run cleans up)."""
    raw = os.fsencode(name)
    if len(raw) <= SHORT_NAME:
        return name
    suffix = os.fsencode(Path(name).suffix)
    return os.fsdecode(raw[:SHORT_NAME - len(suffix)] + suffix)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a temporary file in the same folder and ``os.replace``."""
    with atomic_file(path) as fh:
        fh.write(data)
    return Path(path)


@contextmanager
def atomic_file(path: str | os.PathLike) -> Iterator[BinaryIO]:
    """A binary file, temporary and beside ``path``, that takes its place (``os.replace``) once the block ends
    without an exception and is removed otherwise: a file too large to hold in memory (an archive of
    thousands of frames) written as it is made, yet appearing whole or not at all. A write that fails (a
    full disk, a folder in the way) is an :class:`~pcreg.errors.OutputError` naming ``path``."""
    with _beside(path) as (fd, _), os.fdopen(fd, "wb", closefd=False) as fh:
        yield fh
        fh.flush()


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[str]:
    """:func:`atomic_file` for a writer that opens the file by its name: the temporary file's path. FFmpeg's muxer
    writes so; through a Python file, a full disk's error reached it inside PyAV's callback and came back as "Error
    in PyAV callback", or was printed as an exception "being dropped"."""
    with _beside(path) as (_, tmp):
        yield tmp


@contextmanager
def _beside(path: str | os.PathLike) -> Iterator[tuple[int, str]]:
    """The temporary file beside ``path`` of :func:`atomic_file` and :func:`atomic_path` (its descriptor, which holds
    its lock, and its path), synced and put in ``path``'s place once the block ends without an exception, else
    removed; a write that fails is an :class:`~pcreg.errors.OutputError` naming ``path``."""
    path = Path(path)
    check_held(path)  # before the folder is made again
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = _held_temporary(path)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    try:
        try:
            yield fd, tmp
            os.fsync(fd)
            publish(tmp, path)  # while the lock is held: a cleaner does not take a file about to be published
        finally:
            os.close(fd)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        # a write to the file or its publishing (no file named, or the temporary one), not an input the block read
        if isinstance(exc, OSError) and exc.filename in (None, tmp, str(path)):
            raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
        raise


def _temporary_prefix(path: Path) -> str:
    return f".{_short(path.name)}."


def _held_temporary(path: Path) -> tuple[int, str]:
    """A new temporary file beside ``path`` (``.NAME.XXXXXXXX.tmp``, open as the returned descriptor) with an
    exclusive ``flock`` held on it until it is closed, which the writer's death releases too: what tells
    :func:`remove_leftovers` a file being written from one a killed writer left. Made again when a cleaner
    removed it before the lock was taken. On a file system without ``flock`` it is written unlocked (a
    cleaner there cannot take a lock either, and removes nothing)."""
    import fcntl

    while True:
        # the folder as the system resolves it: mkstemp's own absolute path would read LINK/.. as LINK's folder
        fd, tmp = tempfile.mkstemp(prefix=_temporary_prefix(path), suffix=".tmp", dir=os.path.realpath(path.parent))
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)  # waits while a cleaner holds it, for as long as an unlink takes
        except OSError:
            return fd, tmp
        except BaseException:
            os.close(fd)
            os.unlink(tmp)
            raise
        if os.fstat(fd).st_nlink:
            return fd, tmp
        os.close(fd)  # a cleaner took it between its making and the lock


#: A temporary file of :func:`atomic_file`: the name it takes the place of, and mkstemp's random part.
_TEMPORARY = re.compile(r"\.(?P<name>.+)\.[a-z0-9_]{8}\.tmp")


def remove_leftovers(folder: str | os.PathLike, names: Iterable[str] | Callable[[str], bool]) -> list[Path]:
    """Remove the temporary files in ``folder`` of :func:`atomic_file` writes of ``names`` (file names, or a
    test of one) that no process is writing any more: left by a writer killed or powered off, the ``flock`` it
    held gone with it. A write under way (its lock held) is left alone. Returns the files removed."""
    import fcntl

    folder = Path(folder)
    wanted = names if callable(names) else {_short(n) for n in names}.__contains__
    try:
        found = [e.name for e in os.scandir(folder) if e.name.endswith(".tmp")]
    except OSError:
        return []
    removed = []
    for name in found:
        match = _TEMPORARY.fullmatch(name)
        if match is None or not wanted(match["name"]):
            continue
        tmp = folder / name
        try:
            fd = os.open(tmp, os.O_RDONLY | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0))
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            tmp.unlink()
            removed.append(tmp)
        except OSError:
            pass  # being written (its lock held), or gone meanwhile
        finally:
            os.close(fd)
    return removed


def publish(tmp: str | os.PathLike, path: str | os.PathLike) -> None:
    """Put a finished temporary file (made by :func:`tempfile.mkstemp` beside ``path``) in ``path``'s place
    with the permissions any new file gets (mkstemp makes it 0600): the last step of every atomic write."""
    os.chmod(tmp, 0o666 & ~_UMASK)
    os.replace(tmp, path)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike, obj: Any) -> Path:
    return atomic_write_text(path, to_json(obj) + "\n")


def atomic_write_csv(path: str | os.PathLike, header: Sequence[str], rows: Iterable[Sequence[Any]]) -> Path:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        writer.writerow([_fmt_cell(v) for v in row])
    return atomic_write_text(path, buf.getvalue())


def _fmt_cell(v: Any) -> Any:
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.6g}"
    return v


#: Characters a table cell's text would be read as Markdown by (a column break, emphasis, code, a link),
#: each written after a backslash; also ``<`` and ``&`` where they would open an HTML tag or an entity.
_MARKDOWN_SPECIAL = frozenset("\\|*`[]")


def shell_word(path: str | os.PathLike) -> str:
    """``path`` as a command a person pastes takes it: quoted (:func:`shlex.quote`), and led by ``./`` where it begins
    with a dash, which the command would read as an option (``--out=-o2``'s ``pcreg view -o2 --web``)."""
    import shlex

    text = os.fspath(path)
    return shlex.quote(f"./{text}" if text.startswith("-") else text)


def markdown_text(text: Any) -> str:
    """``text`` as it reads, for one cell of a Markdown table: each Markdown or HTML character after a
    backslash (``a|b`` stays one cell, ``<script>`` and ``&amp;`` show as written; ``_`` only where it could
    be emphasis) and each line break a space."""
    text = " ".join(str(text).splitlines())
    return "".join("\\" + ch if _special(text, i) else ch for i, ch in enumerate(text))


def _special(text: str, i: int) -> bool:
    """Whether ``text[i]`` would be read as Markdown or HTML: ``<`` before a letter, ``/``, ``!`` or ``?`` (a
    tag; ``<= 1`` is text), ``&`` before a letter, digit or ``#`` (an entity), ``_`` outside a word."""
    ch, after = text[i], text[i + 1:i + 2]
    if ch == "<":
        return after.isalpha() or after in ("/", "!", "?")
    if ch == "&":
        return after.isalnum() or after == "#"
    if ch == "_":
        return not _inside_word(text, i)
    return ch in _MARKDOWN_SPECIAL


def _inside_word(text: str, i: int) -> bool:
    """Whether ``text[i]`` has a letter or digit on both sides (an ``_`` there is no emphasis: ``pcreg_half``)."""
    return 0 < i < len(text) - 1 and text[i - 1].isalnum() and text[i + 1].isalnum()


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[Any]], *, digits: int = 2) -> str:
    """A GitHub-flavoured Markdown table; floats rounded to ``digits``; text as it reads (:func:`markdown_text`)."""

    def cell(v: Any) -> str:
        if isinstance(v, (float, np.floating)):
            return "nan" if not np.isfinite(v) else f"{float(v):.{digits}f}"
        return markdown_text(v)

    lines = ["| " + " | ".join(map(markdown_text, header)) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


#: Installed fonts that hold the scripts matplotlib's DejaVu Sans lacks (Chinese, Japanese, Korean, Arabic, Hebrew,
#: Devanagari, Thai): a figure's text falls back to them glyph by glyph, so that a clip's or a class's name in
#: those scripts is drawn, not as boxes.
OTHER_SCRIPT_FONTS = ("Noto Sans CJK JP", "Noto Sans CJK SC", "Noto Sans CJK TC", "Noto Sans CJK KR", "Source Han Sans",
                      "WenQuanYi Zen Hei", "WenQuanYi Micro Hei", "Droid Sans Fallback", "IPAexGothic", "IPAGothic",
                      "Noto Sans Arabic", "Noto Sans Hebrew", "Noto Sans Devanagari", "Noto Sans Thai")


def pyplot() -> Any:
    """matplotlib's ``pyplot``, drawing off screen (Agg). While the font family is still matplotlib's default, the
    installed fonts of :data:`OTHER_SCRIPT_FONTS` are added after DejaVu Sans, as matplotlib's fallback; a
    character no font holds is drawn as matplotlib's placeholder, and its warning (two lines a character on
    stderr, for each figure drawn) is not printed: the reports' tables give the names as text."""
    import warnings

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import font_manager

    if list(matplotlib.rcParams["font.family"]) == ["sans-serif"]:
        installed = {f.name for f in font_manager.fontManager.ttflist}
        others = [name for name in OTHER_SCRIPT_FONTS if name in installed]
        if others:
            matplotlib.rcParams["font.family"] = ["DejaVu Sans", *others, "sans-serif"]
    warnings.filterwarnings("ignore", message=r"Glyph \d+ .*missing from font", category=UserWarning)
    return plt


def atomic_save_figure(fig: Any, path: str | os.PathLike, *, dpi: int = 110) -> Path:
    """Save a matplotlib figure atomically as PNG."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    return atomic_write_bytes(path, buf.getvalue())


def check_output(path: str | os.PathLike, *, force: bool, inputs: tuple = ()) -> Path:
    """Refuse to overwrite an existing file unless ``force``, and one of the command's ``inputs`` (paths) even
    then; check that its folder is writable."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path} is a folder; give a file name")
    check_not_input(path, inputs)
    if path.is_symlink() and not path.exists() and not force:  # a link to nothing, or a loop of links
        raise OutputError(f"{path} exists, a symbolic link to nothing (use --force to overwrite)")
    if path.exists() and not path.is_file():
        raise OutputError(f"{path} is not a regular file")
    if path.exists() and not force:
        # what a write of it killed midway left beside it (with --force: the write's own first step) goes
        remove_leftovers(path.parent, [path.name])
        raise OutputError(f"{path} exists (use --force to overwrite)")
    parent = path.parent if str(path.parent) else Path(".")
    if parent.exists() and not os.access(parent, os.W_OK):
        raise OutputError(f"cannot write {path}: folder is not writable")
    if parent.exists() and not parent.is_dir():
        raise OutputError(f"cannot write {path}: {parent} is not a folder")
    return path


def check_not_input(path: str | os.PathLike, inputs: tuple = ()) -> None:
    """An :class:`~pcreg.errors.OutputError` when ``path`` is one of the command's ``inputs`` (paths, None skipped),
    links followed: an output written there would overwrite it, ``--force`` or not."""
    for given in inputs:
        if given is not None and _same_file(Path(path), given):
            raise OutputError(f"{path} is the input {given}; the output would overwrite it (choose another file)")


def _same_file(a: Path, b: str | os.PathLike) -> bool:
    """Whether ``a`` and ``b`` name one existing file (links followed; False when either cannot be read)."""
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


#: The output folders an :class:`OutputLock` of this process holds (absolute paths) and the (device, inode) of each
#: one's lock file: what :func:`check_held` compares.
_HELD: dict[Path, tuple[int, int]] = {}


def check_held(path: str | os.PathLike) -> None:
    """An :class:`OutputError` when ``path`` lies in an output folder this process holds an :class:`OutputLock` on,
    and that folder's lock file is not the one held any more: the folder was removed, moved or replaced while the
    command wrote into it. A write there would make the folder again, without the lock or what was written before,
    and the command would end as if whole."""
    if not _HELD:
        return
    path = Path(os.path.realpath(path))
    for folder, held in list(_HELD.items()):  # another thread may take or release a lock meanwhile
        if folder in path.parents:
            try:
                st = os.stat(folder / OutputLock.NAME)
            except OSError:
                st = None
            if st is None or (st.st_dev, st.st_ino) != held:
                raise OutputError(f"{folder}: the output folder was removed, moved or replaced while pcreg wrote into "
                                  "it; nothing more is written there (the same command again starts it, or resumes "
                                  "it where the folder is put back)")


class OutputLock:
    """An exclusive lock on an output folder (``fcntl.flock`` on ``FOLDER/.pcreg.lock``), held while a
    command writes there and released on exit (also when the process dies). A second run on the same
    folder gets an :class:`OutputError` at once instead of racing the first. A folder the lock made, that
    holds nothing but the lock when it is released (a command that stopped on bad input before writing),
    is removed again, with the parents the lock made for it."""

    NAME = ".pcreg.lock"

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)
        self._fd: int | None = None
        self._key: Path | None = None  # this lock's entry in _HELD
        self._made: list[Path] = []  # the folders the lock made, the innermost first

    def __enter__(self) -> "OutputLock":
        import fcntl

        if self.folder.exists() and not self.folder.is_dir():
            raise OutputError(f"{self.folder} exists and is not a folder")
        if self.folder.is_symlink() and not self.folder.exists():  # mkdir said "File exists" of it
            raise OutputError(f"{self.folder} is a symbolic link to {os.path.realpath(self.folder)}, which does not "
                              "exist: make that folder, or choose another --out")
        try:
            self._made = [p for p in (self.folder, *self.folder.parents) if not p.exists()]
            self.folder.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.folder / self.NAME, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o666)
        except OSError as exc:
            raise OutputError(f"cannot write to {self.folder}: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            other = _pid_in(fd)
            os.close(fd)
            who = f" (pid {other})" if other else ""
            raise OutputError(f"{self.folder} is in use by another pcreg run{who}; wait for it or use another --out") from None
        self._fd = fd
        try:
            st = os.fstat(fd)
            self._key = Path(os.path.realpath(self.folder))  # as it is now: the working folder may change
            _HELD[self._key] = (st.st_dev, st.st_ino)
            os.ftruncate(fd, 0)
            os.pwrite(fd, str(os.getpid()).encode(), 0)
        except OSError as exc:  # a full disk: the lock's own file named, and the folders it made removed
            self.__exit__()
            raise OutputError(f"cannot write {self.folder / self.NAME}, the lock on the output folder: "
                              f"{exc.strerror or exc}") from None
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._key is not None:
            _HELD.pop(self._key, None)
            self._key = None
        if self._fd is not None:
            try:
                os.ftruncate(self._fd, 0)
            except OSError:
                pass
            self._remove_unused()  # while the lock is held: no other command can have taken the folder
            os.close(self._fd)  # closing releases the flock
            self._fd = None

    def _remove_unused(self) -> None:
        """Remove the folders the lock made when nothing but the lock was written into them."""
        if not self._made:
            return
        try:
            if [e.name for e in os.scandir(self.folder)] != [self.NAME]:
                return
            (self.folder / self.NAME).unlink()
            for made in self._made:
                made.rmdir()  # an OSError (not empty: another command wrote there) stops here
        except OSError:
            pass


def writer_of(folder: str | os.PathLike) -> str | None:
    """Who holds :class:`OutputLock` on ``folder`` now: the process id as text ("" when it wrote none), or None
    when no command is writing there (no lock file, or one nobody holds: a finished or killed command's)."""
    import fcntl

    try:
        fd = os.open(Path(folder) / OutputLock.NAME, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except OSError:
        return _pid_in(fd)
    finally:
        os.close(fd)  # a shared lock taken is released with it
    return None


def _pid_in(fd: int) -> str:
    """The process id an :class:`OutputLock` holder wrote in its lock file (open as ``fd``), "" when none."""
    try:
        text = os.pread(fd, 64, 0).decode("ascii", "replace").strip()
    except OSError:
        return ""
    return text if text.isdigit() else ""


class WriteBehind:
    """Calls run in order on a thread of their own, at most ``depth`` waiting, while the caller goes on:
    ``pcreg run`` writes a frame's outputs (its label PNG, its line of steps.jsonl, the carry and the
    run.json that commits them) while it labels the next frame. Encoding releases the GIL and
    ``fsync`` waits on the disk, so the writing costs the step little.

    An error of a call is raised in the caller, at its next :meth:`submit` or when the ``with`` block
    ends, and nothing after it is written. Leaving the block, on an error or an interrupt as well, first
    lets the calls already submitted finish: the last frame committed is a whole one, and a run resumes
    after it.
    """

    def __init__(self, depth: int = 2, *, name: str = "pcreg-write-behind") -> None:
        import queue
        import threading

        self._box: queue.Queue = queue.Queue(maxsize=depth)
        self._error: BaseException | None = None  # to raise in the caller, once
        self._failed = False  # and from then on nothing is written
        self._thread = threading.Thread(target=self._work, name=name, daemon=True)
        self._thread.start()

    def _work(self) -> None:
        while True:
            item = self._box.get()
            if item is None:
                return
            if not self._failed:  # after an error nothing more is written
                fn, args, kwargs = item
                try:
                    fn(*args, **kwargs)
                except BaseException as exc:  # noqa: BLE001 - handed to the caller, raised in its thread
                    self._error, self._failed = exc, True

    def submit(self, fn, /, *args: Any, **kwargs: Any) -> None:
        """Run ``fn(*args, **kwargs)`` after the calls submitted before (waiting while ``depth`` wait)."""
        self._raise()
        self._box.put((fn, args, kwargs))

    def _raise(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error

    def close(self) -> None:
        """Wait for every call submitted, then raise the first error of one."""
        if self._thread.is_alive():
            self._box.put(None)
            self._thread.join()
        self._raise()

    def __enter__(self) -> "WriteBehind":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        elif self._thread.is_alive():  # the error under way is the one to report
            self._box.put(None)
            self._thread.join()
