"""Text clouds read by pcreg itself: a text file of columns (.txt, .csv: what ``numpy.savetxt``, pycpd's,
probreg's and libpointmatcher's data and most exports hold) through :func:`read_columns`, and a .pts cloud as
Leica Cyclone and CloudCompare write it through :func:`read_pts`; and the check of the text clouds Open3D reads
(.xyz, .xyzn, .xyzrgb). Whatever a reader would skip or read in part is refused in one line naming the file
(:class:`~pcreg.errors.InputError`)."""

from __future__ import annotations

import csv
import itertools
import os
import re
import warnings
from pathlib import Path
from typing import Callable

import numpy as np

from .cloud_files import _ASCII_NUMBER, _scan_rows
from .errors import InputError
from .text_files import refuse_utf16
from .validation import check_point_count, max_pixels

__all__ = ["UTF8_BOM", "check_last_line", "check_text_cloud", "number_columns", "read_columns", "read_pts"]


def check_text_cloud(path: Path, suffix: str, limit: int) -> tuple[int, int]:
    """How many points a text cloud holds, and how many numbers a line, checked before it is read: Open3D reads
    a line with C's ``sscanf``, skipping a line it cannot parse and reading what a line starts with (``3,5`` as
    3, ``3abc`` as 3, ``0x10`` as 16), and a .pts file's first line declares its count (a count of 20 million in
    a file of three lines took 800 MB in Open3D's reader). Every non-empty line is a point of as many plain
    numbers as the first (``.pts``: after a first line with the point count, which must be theirs), as many as
    the format needs, and their count within ``limit``; no byte-order mark, and no line end that is a carriage
    return alone (Open3D reads such a file as one line: its first point); else an :class:`InputError`."""
    with open(path, "rb") as fh:  # streamed: the file may be large
        firsts = list(itertools.islice((line.strip() for line in fh if line.strip()), 2))
    if firsts:
        refuse_utf16(path, firsts[0])
    if firsts and firsts[0].startswith(UTF8_BOM):  # Open3D's reader takes it for the start of the first number
        raise InputError(f"{path}: it starts with a UTF-8 byte-order mark, which the {suffix} reader does not "
                         "read past; save the file without it")
    if firsts and b"\r" in firsts[0]:  # one line to Open3D, which reads its first point and drops the rest
        raise InputError(f"{path}: its lines end in a carriage return alone (as classic Mac OS wrote them), which "
                         f"the {suffix} reader takes for one line (one point); save it with LF or CR LF line ends")
    header = 1 if suffix == ".pts" and firsts and firsts[0].isdigit() else 0
    if suffix == ".pts" and firsts and not header:  # Open3D read its number as the count: one point, or none
        raise InputError(f"{path}: its first line ({firsts[0][:40].decode('ascii', 'replace')!r}) is not the point "
                         "count a .pts file starts with")
    width = len(firsts[header].split()) if len(firsts) > header else 1
    count, bad = _scan_rows(path, 0, stop=1 << 62, rows=(header, 1 << 62), fields=width)
    expected = count - header
    text = "" if bad is None else shown(bad[1].strip())
    if bad is not None and text.startswith(("#", "//")):  # numpy.savetxt's header, CloudCompare's //X Y Z: no damage
        where = "its first point line" if bad[0] == 1 else f"point line {bad[0]}"
        passed = " (Open3D's reader passes over it)" if suffix != ".pts" else ""
        raise InputError(f"{path}: {where} ({text!r}) is a comment, which a {suffix} file does not hold{passed}; save "
                         "the points without comment lines, or as .txt or .csv, whose lines starting with # pcreg skips")
    if header and int(firsts[0]) != expected:
        raise InputError(f"{path}: the first line declares {int(firsts[0])} points, the file holds {expected} lines")
    if bad is not None:
        number = bad[0]
        if number == 1:
            raise InputError(f"{path}: its first point line ({text!r}) is not numbers between white space "
                             f"({odd_character(bad[1]) or f'damaged {suffix} file'})")
        raise InputError(f"{path}: point line {number} ({text!r}) is not {width} numbers, as the first is "
                         f"({odd_character(bad[1]) or f'damaged {suffix} file'})")
    check_point_count(expected, str(path), limit=limit)
    need, what = _TEXT_NUMBERS.get(suffix, (0, ""))
    if expected and width < need:  # Open3D's reader skips every such line: no point read
        raise InputError(f"{path}: its point lines hold {width} number{'s' if width > 1 else ''} ({what} are "
                         f"needed{_TWO_D if width == 2 else ''})")
    return expected, width


#: How many numbers a line of each text cloud Open3D reads needs, and what they are.
_TEXT_NUMBERS = {".xyz": (3, "x, y and z"), ".xyzn": (6, "x, y, z and a normal"),
                 ".xyzrgb": (6, "x, y, z and a colour")}
#: Said of a text cloud of two numbers a line that needs three.
_TWO_D = "; a 2-D cloud is read from a .csv or .txt file of two columns, or an (N, 2) .npy"


def read_pts(path: Path, limit: int) -> np.ndarray:
    """The x, y, z (N, 3) of a .pts cloud as Leica Cyclone and CloudCompare write it: a first line with the point
    count, then a point a line, its first three numbers x, y and z and the rest what the scanner adds (``x y z
    intensity r g b``, ``x y z intensity``, ``x y z r g b``, colours whole or fractions), left out. Its lines are
    checked first (:func:`check_text_cloud`: the count there and theirs, every line as many plain numbers as the
    first, within the limit). Open3D's reader refuses an intensity ("only points and colors attributes are
    supported") and fractional colours."""
    count, width = check_text_cloud(path, ".pts", limit)
    if count == 0:
        raise InputError(f"{path}: no points could be read (a point count of 0)")
    if width < 3:
        raise InputError(f"{path}: its point lines hold {width} number{'s' if width > 1 else ''} (x, y and z are "
                         "needed)")
    return number_columns(path, (0, 1, 2), count, after_first_line=True)


def number_columns(path: Path, columns, count: int, *, start: int = 0, after_first_line: bool = False) -> np.ndarray:
    """(count, len(columns)) float64: the ``columns`` of the ``count`` point lines of a checked text cloud, from
    byte ``start`` (an ASCII PCD's data) or after its first non-blank line (a .pts file's count), split at
    newlines only (as the checks do: a CR is white space between numbers); ``nan(ind)`` and its kind, as C's
    printf writes a NaN on some systems, read as NaN."""
    try:
        return _number_columns(path, columns, count, start, after_first_line, None)
    except ValueError:
        return _number_columns(path, columns, count, start, after_first_line, lambda word: float(word.split("(")[0]))


def _number_columns(path: Path, columns, count: int, start: int, after_first_line: bool,
                    converter: Callable[[str], float] | None) -> np.ndarray:
    with open(path, "rb") as fh, warnings.catch_warnings():  # blank lines are not counted in max_rows: no warning
        warnings.simplefilter("ignore", UserWarning)
        fh.seek(start)
        lines = (line.decode("latin-1").replace("\r", " ") for line in fh)
        if after_first_line:
            next(line for line in lines if line.strip())
        return np.loadtxt(lines, dtype=np.float64, comments=None, usecols=columns, ndmin=2, max_rows=count,
                          converters=converter)


_NUMBER = re.compile(_ASCII_NUMBER)
#: What a spreadsheet's "CSV UTF-8" export starts with (Excel's): no part of the first line's names or numbers.
UTF8_BOM = b"\xef\xbb\xbf"


def read_columns(path: str | os.PathLike, limit: int | None = None) -> np.ndarray:
    """The points of a text file of columns: one point a line, its fields separated by commas, by semicolons
    or by spaces and tabs (which of them, the first line says), a field in double quotes read as what they
    enclose (as csv writers and spreadsheets quote), a comma between semicolons or tabs read as the decimal mark
    (``1,5;2,25``, as spreadsheets in European locales write); blank lines and lines starting with ``#``
    skipped. Two or three numbers a line are x, y (and z); a first line of names (each of x, y, z once; ``x,y,z,nx,ny,nz`` as
    libpointmatcher writes, ``//X,Y,Z,R,G,B`` as CloudCompare does) says which columns are x, y and z, in any
    number of columns, the others read or not (a column of text, ``x,y,z,label``, is left out). Every line must
    hold as many fields as the first, and numbers where x, y and z are: a line that does not is an
    :class:`InputError` naming it (a reader that skipped it would register a cloud the file does not hold)."""
    path = Path(path)
    lim = max_pixels(limit)
    first, line_number = _first_line(path)
    if first is None:
        raise InputError(f"{path}: no points could be read (no line of numbers)")
    refuse_utf16(path, first)  # read as bytes, every other one a zero
    if b"\r" in first:  # one line to the reader: its first point, or a first line of names it is not
        raise InputError(f"{path}: its lines end in a carriage return alone (as classic Mac OS wrote them); save it "
                         "with LF or CR LF line ends")
    separator = _separator(first, _next_line(path, line_number))
    fields = _split(first, separator, path, line_number)
    columns = _columns(path, fields)
    skip = line_number if columns else 0
    try:  # numpy's parser: strict (no "1_0", no "1,0" between spaces), and many times faster than a loop here
        data = _load_columns(path, separator, skip, lim, None)
        named = False
    except ValueError as exc:
        if columns is None:
            _bad_line(path, separator, len(fields), skip + 1, None)
            raise InputError(f"{path}: cannot read its columns ({str(exc).split(';')[0][:120]})") from None
        # named columns, others not numbers (text): each line's fields counted here, x, y and z read alone
        _bad_line(path, separator, len(fields), skip + 1, columns)
        try:
            data = _load_columns(path, separator, skip, lim, columns)
        except ValueError as again:
            raise InputError(f"{path}: cannot read its columns ({str(again).split(';')[0][:120]})") from None
        named = True
    if len(data) > lim:
        raise InputError(f"{path}: more than {lim} points exceed the limit (raise --max-pixels or PCREG_MAX_PIXELS)")
    if len(data) == 0:
        raise InputError(f"{path}: no points could be read (a first line of names and no line of numbers)")
    if named:
        return data
    if data.shape[1] != len(fields):
        raise InputError(f"{path}: {data.shape[1]} numbers a line under a first line of {len(fields)} names")
    return np.ascontiguousarray(data[:, columns]) if columns else data


def _load_columns(path: Path, separator: bytes | None, skip: int, lim: int, usecols: list[int] | None) -> np.ndarray:
    """The numbers of the lines after the first ``skip`` (at most ``lim`` + 1 of them), the ``usecols`` columns
    (None: all), a field in double quotes read as its content (as a spreadsheet or ``csv.QUOTE_ALL`` writes it) and,
    between semicolons or tabs, a comma as the decimal mark; a ValueError where a line is not numbers there.

    numpy reserves ``max_rows`` rows of as many numbers as the first line holds before it reads a second: a line
    of 201 numbers under a limit of 50 million points reserved 75 GiB. The rows are bounded first by what the file
    can hold (each row at least a byte a number)."""
    options: dict = {} if separator is None else {"delimiter": separator.decode(), "quotechar": '"'}
    if separator in _DECIMAL_COMMA_SEPARATORS:
        options["converters"] = _decimal_comma_float

    def load(max_rows: int) -> np.ndarray:
        with warnings.catch_warnings():  # blank lines not counted in max_rows, no data: said here, not on stderr
            warnings.simplefilter("ignore", UserWarning)
            with open(path, "rb") as fh:
                fh.seek(len(UTF8_BOM) if fh.read(len(UTF8_BOM)) == UTF8_BOM else 0)
                return np.loadtxt(fh, dtype=np.float64, comments="#", skiprows=skip, ndmin=2, max_rows=max_rows,
                                  encoding="latin-1", usecols=usecols, **options)

    first = load(1)
    if first.size == 0:
        return first
    return load(min(lim + 1, path.stat().st_size // first.shape[1] + 1))


#: The separators between which a comma is a decimal mark, as spreadsheets in most European locales write
#: (``1,5;2,25;-3,0``; Excel's CSV there separates with semicolons, its text export with tabs).
_DECIMAL_COMMA_SEPARATORS = (b";", b"\t")
#: A number with a decimal comma.
_COMMA_NUMBER = re.compile(rb"[+-]?(?:\d+,\d*|,\d+)(?:[eE][+-]?\d+)?")


def _decimal_comma_float(text: str) -> float:
    return float(text.replace(",", ".", 1) if "." not in text else text)


def _unquoted(line: bytes) -> bytes:
    """``line`` without what its double quotes enclose (where a separator is looked for)."""
    return re.sub(rb'"[^"]*"', b"", line)


def _separator(first: bytes, second: bytes | None) -> bytes | None:
    """The fields' separator the first line says (outside quotes): a semicolon; a tab between numbers with decimal
    commas; a comma; else white space (None). Under a first line of names apart by white space, the next line
    says whether tabs separate numbers with decimal commas (its other commas are a text column's)."""
    bare = _unquoted(first)
    if b";" in bare:
        return b";"
    if _tabbed_commas(bare):
        return b"\t"
    if b"," in bare:
        return b","
    if second is not None and not all(_NUMBER.fullmatch(w) for w in bare.split()) and _tabbed_commas(_unquoted(second)):
        return b"\t"
    return None


def _tabbed_commas(line: bytes) -> bool:
    """Whether ``line`` is numbers between tabs, one with a decimal comma or more."""
    tabs = [w.strip() for w in line.split(b"\t")]
    return (b"," in line and len(tabs) > 1
            and all(_COMMA_NUMBER.fullmatch(w) or _NUMBER.fullmatch(w) for w in tabs))


def _next_line(path: Path, after: int) -> bytes | None:
    """The first line after line ``after`` that is neither blank nor a ``#`` comment, stripped."""
    with open(path, "rb") as fh:
        for raw in itertools.islice(fh, after, None):
            line = raw.strip()
            if line and not line.startswith(b"#"):
                return line
    return None


def _first_line(path: Path) -> tuple[bytes | None, int]:
    """The first line that is neither blank nor a ``#`` comment, stripped (of a byte-order mark too), and its
    number (from 1)."""
    with open(path, "rb") as fh:
        for number, raw in enumerate(fh, 1):
            line = (raw.removeprefix(UTF8_BOM) if number == 1 else raw).strip()
            if line and not line.startswith(b"#"):
                return line, number
    return None, 0


def _split(line: bytes, separator: bytes | None, path: Path, number: int) -> list[bytes]:
    """The fields of ``line`` (its ``number``), as :func:`_load_columns` reads them: a field in double quotes as its
    content, and a decimal comma between semicolons or tabs as a point; an unclosed quote is an :class:`InputError`."""
    if separator is None:
        fields = line.split()
    elif b'"' not in line:
        fields = [f.strip() for f in line.split(separator)]
    else:
        try:
            row = next(csv.reader([line.decode("latin-1")], delimiter=separator.decode(), skipinitialspace=True,
                                  strict=True))
        except csv.Error:
            text = line[:40].decode("ascii", "replace")
            raise InputError(f"{path}: line {number} ({text!r}) has a quote that does not close on that line") from None
        fields = [f.strip().encode("latin-1") for f in row]
    if separator in _DECIMAL_COMMA_SEPARATORS:
        fields = [f.replace(b",", b".") if _COMMA_NUMBER.fullmatch(f) else f for f in fields]
    return fields


def _bad_line(path: Path, separator: bytes | None, width: int, start: int, numeric: list[int] | None) -> None:
    """An :class:`InputError` naming the first line from line ``start`` on that is not ``width`` fields, numbers
    in the ``numeric`` columns (None: in every column); a line of other fields is said to be so once a line has
    held text beside them, else not as many numbers as the first."""
    text_seen = False
    with open(path, "rb") as fh:
        for number, raw in enumerate(fh, 1):
            line = (raw.removeprefix(UTF8_BOM) if number == 1 else raw).strip()
            if number < start or not line or line.startswith(b"#"):
                continue
            fields = _split(line, separator, path, number)
            checked = range(len(fields)) if numeric is None else numeric
            wrong = next((k for k in checked if k >= len(fields) or not _NUMBER.fullmatch(fields[k])), None)
            if len(fields) == width and wrong is None:
                text_seen = text_seen or not all(_NUMBER.fullmatch(f) for f in fields)
                continue
            text, odd = shown(line), odd_character(line)
            odd = f"; it holds {odd}" if odd else ""
            if not raw.endswith(b"\n"):
                raise InputError(f"{path}: line {number} ({text!r}) is cut short")
            if numeric is None or (len(fields) != width and not text_seen):
                raise InputError(f"{path}: line {number} ({text!r}) is not {width} numbers, as the first{odd}")
            if len(fields) != width or wrong is None:
                raise InputError(f"{path}: line {number} ({text!r}) has {len(fields)} fields, the first line names "
                                 f"{width}")
            raise InputError(f"{path}: line {number} ({text!r}): its {'xyz'[numeric.index(wrong)]}, "
                             f"{shown(fields[wrong], 20)!r}, is not a number{odd or _comma_hint(line)}")


#: How much of a text cloud's end :func:`check_last_line` reads, and how many whole lines before its last it
#: compares the last with (at least :data:`_CUT_LINES_MIN` of them).
_TAIL_BYTES, _CUT_LINES, _CUT_LINES_MIN = 1 << 14, 32, 3
#: A number's shape as a writer's format gives it: its sign, digits, point, digits and exponent.
_SHAPE = re.compile(rb"[+-]?\d*(?:\.(\d*))?(?:[eE]([+-]?\d*))?")


def check_last_line(path: Path) -> None:
    """An :class:`InputError` for a text cloud cut inside its last number: a last line with no line end whose
    last number is shorter than that column's on every line before it of as many fields (``3.8`` where each is
    written ``3.842e-01``, or with six digits after the point, trailing zeros kept), as a file written with one
    format and then cut short
    (an interrupted copy or download) ends. A line cut between two numbers is refused where its count of
    numbers is checked; one cut inside a number has the right count, and a reader takes the rest of it for
    the number. A last line that ends with a line end, or a column written in varying lengths (``%g``), says
    nothing, and a binary file's end holds no such lines."""
    with open(path, "rb") as fh:
        start = max(0, fh.seek(0, os.SEEK_END) - _TAIL_BYTES)
        fh.seek(start)
        tail = fh.read()
    if not tail or tail.endswith((b"\n", b"\r")):
        return
    lines = [line for line in tail.split(b"\n")[1 if start else 0:] if line.strip()]  # the first may start mid-line
    if not lines:
        return
    fields = len(_FIELDS.split(lines[-1].strip()))
    last, before, formats, zeros = _last_number(lines[-1]), [], set(), False
    for line in reversed(lines[-_CUT_LINES - 1:-1]):  # the lines of numbers just before it (not a header's, nor
        word = _last_number(line)  # another element's, as a PLY's last face after its vertices)
        shape = _SHAPE.fullmatch(word)
        if shape is None or not any(c in b"0123456789" for c in word) or len(_FIELDS.split(line.strip())) != fields:
            break
        before.append(word)
        formats.add(_digits(shape))
        zeros = zeros or (shape.group(1) or b"").endswith(b"0")
    shape = _SHAPE.fullmatch(last)
    if len(before) < _CUT_LINES_MIN or not last or shape is None or len(formats) > 1:
        return  # too few lines to tell, no number (a line cut after a separator: its count is checked), a column of no one format
    (after, exponent), (whole_after, whole_exponent) = _digits(shape), formats.pop()
    # fewer digits after the point tell a cut only where the writer keeps trailing zeros (one of those before ends
    # in 0): a column of %g or of rounded numbers can hold one count of them by chance, and drop a last 0
    if (after < whole_after and zeros) or exponent < whole_exponent:
        raise InputError(f"{path}: its last line ends inside a number: {shown(last, 30)!r} is shorter than that column "
                         f"on every line before it ({shown(before[0], 30)!r}) and no line end follows it, as a file cut "
                         "short (an interrupted copy or download) ends; copy the file again (a last line that is "
                         "whole is read once it ends with a line end)")


#: What separates the fields of a text cloud's line, as :func:`check_last_line` splits them.
_FIELDS = re.compile(rb"[\s,;]+")


def _last_number(line: bytes) -> bytes:
    """The last of a line's fields (:data:`_FIELDS`), its quotes taken off."""
    words = _FIELDS.split(line.strip())
    return words[-1].strip(b'"') if words else b""


def _digits(shape: re.Match) -> tuple[int, int]:
    """A number's digits after its point and in its exponent (:data:`_SHAPE`), each -1 where it has none."""
    after, exponent = shape.group(1), shape.group(2)
    return (-1 if after is None else len(after), -1 if exponent is None else len(exponent.lstrip(b"+-")))


def shown(line: bytes, size: int = 40) -> str:
    """The first ``size`` characters of a line of a text cloud as a refusal quotes it: its UTF-8 as written (a
    no-break space or a minus sign shown as itself), bytes that are none replaced."""
    return line.decode("utf-8", "replace")[:size]


def odd_character(line: bytes) -> str:
    """What a refusal of a ``line`` of numbers says of the first character a word processor writes in one (a
    no-break space, a minus sign, a dash) where the line holds digits: its name and what to do; '' otherwise."""
    import unicodedata

    odd = next((c for c in line.decode("utf-8", "replace") if ord(c) > 127), None)
    if odd is None or unicodedata.category(odd) not in ("Zs", "Pd", "Sm") or not any(c in b"0123456789" for c in line):
        return ""
    return (f"{unicodedata.name(odd, 'a character')} (U+{ord(odd):04X}), no digit, sign or separator of a number: save "
            "the cloud as plain text ('-' for a minus, spaces or commas between the numbers)")


#: Said of a line of numbers with decimal commas between spaces (``1,5 2,5``), which is refused.
DECIMAL_COMMA_HINT = (" (decimal commas are read between semicolons or tabs, as a spreadsheet saves them; between "
                      "spaces a comma is taken for a separator: save with ';' or tabs between the numbers)")


def _comma_hint(line: bytes) -> str:
    """:data:`DECIMAL_COMMA_HINT` when a word of ``line`` (split at white space) is a number with a decimal
    comma, else ""."""
    return DECIMAL_COMMA_HINT if any(_COMMA_NUMBER.fullmatch(w) for w in line.split()) else ""


#: ParaView's CSV export names the coordinates ``Points:0``, ``Points:1``, ``Points:2``, and VTK-derived writers
#: ``Points_0``, ...: read as x, y and z in a first line that names no x and y.
_POINTS_COLUMNS = {f"points{sep}{k}": a for k, a in enumerate("xyz") for sep in (":", "_")}


def _columns(path: Path, fields: list[bytes]) -> list[int] | None:
    """None for a first line of numbers with two or three of them; the x, y (and z) columns of a first line of
    names (:data:`_POINTS_COLUMNS` stand for them); an :class:`InputError` otherwise (numbers in other counts say
    nothing of which are coordinates)."""
    if all(_NUMBER.fullmatch(f) for f in fields):
        if len(fields) in (2, 3):
            return None
        raise InputError(f"{path}: {len(fields)} number{'s' if len(fields) > 1 else ''} a line and no first line naming the x, y and z columns "
                         "(give one, as 'x y z ...', or keep two or three columns)")
    filled = len(fields)
    while filled and not fields[filled - 1].strip():
        filled -= 1
    if 0 < filled < len(fields) and all(_NUMBER.fullmatch(f) for f in fields[:filled]):
        raise InputError(f"{path}: its first line is {filled} numbers and then an empty field (a separator at the "
                         f"end of the line, as some spreadsheets save): which columns are x, y and z is not said "
                         f"(remove the separators at the ends of the lines, or add a first line naming the columns, "
                         f"as 'x,y,z,')")
    names = [f.decode("ascii", "replace").strip("\"'").lstrip("/").strip().lower() for f in fields]
    if "x" not in names and "y" not in names:
        names = [_POINTS_COLUMNS.get(n, n) for n in names]
    twice = next((a for a in "xyz" if names.count(a) > 1), None)
    if twice is not None:  # which of them holds the coordinate, the file does not say ('x,x,z': y is not the matter)
        first, second = [k for k, name in enumerate(names) if name == twice][:2]
        raise InputError(f"{path}: its first line names {twice} twice (columns {first + 1} and {second + 1}); keep "
                         "one of them")
    if "x" not in names or "y" not in names:
        line = b",".join(fields)
        odd = odd_character(line)
        if odd:
            raise InputError(f"{path}: its first line holds {odd}")
        text = line[:60].decode("utf-8", "replace")
        raise InputError(f"{path}: its first line ({text!r}) names no x and y columns{_comma_hint(line)}")
    return [names.index(a) for a in "xyz" if a in names]
