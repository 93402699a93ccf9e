"""DAVIS's splits: which sequences of an official download the benchmark evaluates (``ImageSets``).

An official download holds more sequences than the benchmark's table: DAVIS 2016 fifty (train thirty, val
twenty), DAVIS 2017 trainval ninety. The published figures pcreg compares with are DAVIS 2016 val's, so with
an official root ``--data davis:ROOT`` evaluates the split its ``ImageSets`` name, ``val`` by default, and
``davis:ROOT:train`` or ``davis:ROOT:all`` choose another (:func:`parse_davis_arg`).

The split files, in the two formats the official downloads ship:

- DAVIS 2016 (``DAVIS/ImageSets/480p/train.txt``, ``val.txt``; ``1080p`` alike): one line a frame, the
  frame's and its mask's paths from ROOT, ``/JPEGImages/480p/bear/00000.jpg /Annotations/480p/bear/00000.png``.
  Loaders of that download read a line as whitespace-separated paths, the sequence being the folder above
  the frame (``fn.split("/")[-2]``).
- DAVIS 2017 (``DAVIS/ImageSets/2017/train.txt``, ``val.txt``, and DAVIS 2016's split again as
  ``ImageSets/2016/train.txt``, ``val.txt``): one sequence name a line, as davisvideochallenge/davis2017-evaluation
  ``davis2017/davis.py`` reads ``ImageSets/2017/{subset}.txt`` (``[x.strip() for x in f.readlines()]``).

Either format is read from any of these files (:func:`read_split_file`); only the sequences matter, every
frame of a listed sequence is evaluated. ``--data davis:ROOT`` with a 2017 download reads
``ImageSets/2016/val.txt``: DAVIS 2016 val, the twenty sequences the shipped figures are of.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..errors import DatasetError, InputError

__all__ = ["SPLITS", "DEFAULT_SPLIT", "DavisSplit", "parse_davis_arg", "split_file", "read_split_file",
           "choose_split"]

#: The split names ``davis:ROOT:SPLIT`` takes: DAVIS 2016's val or train, or every sequence folder.
SPLITS: tuple[str, ...] = ("val", "train", "all")
#: The split evaluated when ``ImageSets`` names one: the benchmark's table is over DAVIS 2016 val.
DEFAULT_SPLIT = "val"


@dataclass(frozen=True)
class DavisSplit:
    """The sequences evaluated: ``name`` (``val``, ``train`` or ``all``), the split ``file`` read (its path
    from ROOT, None for all), the ``sequences`` in name order and how many sequence folders there are
    (``available``)."""

    name: str
    file: str | None
    sequences: tuple[str, ...]
    available: int
    why: str = ""  #: why every sequence (with ``all``): asked for, or no split file at the root
    resolution: str | None = None  #: the official layout's resolution folder read (None: pcreg's layout)

    def describe(self) -> str:
        """One line: ``DAVIS 2016 val (ImageSets/480p/val.txt): 20 of 50 sequences``, and the frames' resolution
        folder when it is not ``480p``, the one the published figures are of."""
        n = len(self.sequences)
        if self.file is not None:
            line = f"DAVIS 2016 {self.name} ({self.file}): {n} of {self.available} sequences"
        else:
            line = (f"all {n} sequences" if n != 1 else "its one sequence") + (f" ({self.why})" if self.why else "")
        if self.resolution not in (None, "480p"):
            line += f"; frames of {self.resolution}/, where the published figures are of 480p/"
        return line

    def to_dict(self) -> dict:
        return {"name": self.name, "file": self.file, "sequences": list(self.sequences),
                "available": self.available, "resolution": self.resolution, "described": self.describe()}


def parse_davis_arg(arg: str) -> tuple[str, str | None]:
    """``PATH`` or ``PATH:SPLIT`` (the part of ``--data davis:...`` after ``davis:``): (PATH, SPLIT or None).

    A PATH that is a folder is taken whole, colons and all; else a last ``:NAME`` (no ``/`` in it) names the
    split, one of :data:`SPLITS` (an :class:`~pcreg.errors.InputError` otherwise)."""
    text = str(arg)
    if Path(text).expanduser().is_dir():
        return text, None
    head, colon, tail = text.rpartition(":")
    if not colon or not head or not tail or "/" in tail or "\\" in tail:
        return text, None
    if tail.strip().lower() not in SPLITS:
        raise InputError(f"--data davis:{text}: {tail!r} is no split ({', '.join(SPLITS)}) and {text} no folder")
    return head, tail.strip().lower()


def split_file(root: Path, resolution: str, split: str) -> Path | None:
    """DAVIS 2016's ``split`` list under ``root/ImageSets``: ``RES/SPLIT.txt`` (the 2016 download, at the
    resolution read, else ``480p``), else ``2016/SPLIT.txt`` (the 2017 download); None when neither is. An entry of
    that name that is no file (a folder, a link to nothing) is returned too, for its reading to name it: taken as
    absent, the root's every sequence was evaluated in the split's place."""
    for sub in dict.fromkeys((resolution, "480p", "2016")):
        f = root / "ImageSets" / sub / f"{split}.txt"
        if f.exists() or f.is_symlink():  # (exists() raises where the folder cannot be read: said, not taken for none)
            return f
    return None


def _sequence_of(line: str) -> str | None:
    """The sequence a split file's line names: the line itself (one name a line), or the folder above the
    frame of ``/JPEGImages/RES/SEQ/FRAME [/Annotations/RES/SEQ/FRAME.png]``; None when it is neither."""
    tokens = line.split()
    if len(tokens) == 1 and "/" not in tokens[0] and "\\" not in tokens[0]:
        return tokens[0]
    if len(tokens) in (1, 2):
        parts = [p for p in tokens[0].split("/") if p]
        if len(parts) >= 4 and parts[-4] == "JPEGImages":
            return parts[-2]
    return None


def read_split_file(path: str | Path) -> list[str]:
    """The sequences a split file names, in its order, each once (either format of the module).

    A :class:`~pcreg.errors.DatasetError` naming the file: unreadable, not UTF-8 text, a line in neither
    format (its number said), or no sequence at all."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")  # a byte-order mark (Notepad's UTF-8) is no part of the first name
    except (OSError, UnicodeDecodeError) as exc:
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        raise DatasetError(f"{path}: cannot read the split file ({why})") from None
    names: dict[str, None] = {}
    for i, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        seq = _sequence_of(line)
        if seq is None:
            raise DatasetError(f"{path}: line {i} is neither a sequence name nor a frame line "
                               f"(/JPEGImages/480p/SEQ/00000.jpg /Annotations/480p/SEQ/00000.png): {line.strip()[:80]!r}")
        names[seq] = None
    if not names:
        raise DatasetError(f"{path}: the split file names no sequence")
    return list(names)


def choose_split(names: list[str], *, root: Path | None, resolution: str | None, split: str | None,
                 where: Path) -> DavisSplit:
    """Which of the sequence folders ``names`` to evaluate: ``split`` (None: :data:`DEFAULT_SPLIT` when
    ``root``'s ``ImageSets`` has its file, else all). ``root`` None: ``where`` is not an official root (pcreg's
    layout, or one sequence), where only ``all`` is.

    A :class:`~pcreg.errors.DatasetError`: a split asked for where there is no split file (naming where it was
    looked for), or a split file naming a sequence that has no folder (naming both)."""
    if split == "all" or (split is None and root is None):
        return DavisSplit("all", None, tuple(names), len(names), ":all asked for" if root is not None else "")
    if root is None or resolution is None:
        raise DatasetError(f"{where}: no DAVIS split here (ImageSets belongs to an official root, "
                           f"ROOT/JPEGImages/480p/SEQ); give the root, or no :{split}")
    f = split_file(root, resolution, split or DEFAULT_SPLIT)
    if f is None and split is None:  # an official root without ImageSets: every sequence, as before
        return DavisSplit("all", None, tuple(names), len(names),
                          f"no ImageSets/{resolution}/val.txt or ImageSets/2016/val.txt in {root}")
    if f is None:
        *subs, last = dict.fromkeys((resolution, "480p", "2016"))  # as split_file looks: 480p once
        raise DatasetError(f"{root / 'ImageSets'}: no {split}.txt under {', '.join(f'{s}/' for s in subs)} or "
                           f"{last}/ (DAVIS 2016's split); give :all for every sequence")
    split = split or DEFAULT_SPLIT
    listed = read_split_file(f)
    have = set(names)
    missing = [n for n in listed if n not in have]
    if missing:
        raise DatasetError(f"{f}: names sequence {missing[0]!r}, which has no folder in "
                           f"{root / 'JPEGImages' / resolution}"
                           + (f" ({len(missing) - 1} more missing)" if len(missing) > 1 else ""))
    wanted = set(listed)
    chosen = tuple(n for n in names if n in wanted)
    return DavisSplit(split, f.relative_to(root).as_posix(), chosen, len(names))
