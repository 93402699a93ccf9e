"""Point-cloud files checked before Open3D or numpy reads them: PLY and PCD (ASCII and binary) whose headers
are sound, whose declared counts are within the limit and match what the file holds, and whose ASCII lines
hold the numbers the header declares; .npy whose header is a plain numeric array. Open3D pads what it cannot
read with zeros (or what its memory held), and aborts the process on some malformed headers: each such file
is refused here in one line naming it."""

from __future__ import annotations

import math
import mmap
import os
import re
import struct
import tokenize
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from .errors import InputError
from .formats import check_regular_file, max_file_bytes
from .validation import check_point_count, max_pixels

__all__ = ["LZF_MOST_UNPACKED", "MAX_HEADER_BYTES", "MAX_PLY_LINE", "NPY_HEADER_ERRORS", "check_npy_file", "check_cloud_file"]


_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


#: The most bytes a point cloud's header is read from (a PLY's comments may run long).
MAX_HEADER_BYTES = 1 << 20
#: The most bytes LZF (a compressed PCD's codec) unpacks from one byte: its longest item, a back reference of
#: 3 bytes, copies 264 (a length of 7 + 255, plus 2); a literal run of k bytes takes k + 1. A block that claims
#: more is damaged, or a bomb: a few hundred bytes declaring gigabytes that Open3D would reserve first.
LZF_MOST_UNPACKED = 264 // 3
#: The longest PLY header line read (bytes): Open3D's reader (RPly) copies each into a buffer of 1,024 and aborts
#: the whole process past it ("buffer overflow detected").
MAX_PLY_LINE = 1000


def header_int(text: str) -> int:
    """A count or size of a point cloud's header as C's readers take it whole: ASCII digits with a sign at most, or a
    ``ValueError``. Python's ``int`` also takes ``16_00``, ``\u0661`` and spaces, where Open3D's readers stop at the
    first other character (``16_00`` is 16): pcreg would check one count and Open3D read another."""
    if re.fullmatch(r"[+-]?[0-9]+", text) is None:
        raise ValueError(f"not a whole number: {text!r}")
    return int(text)


def _ply_header(path: Path) -> tuple[str, list[list], int]:
    """``(format, elements, body_start)`` of a PLY's header, each element ``[name, count, [sizes], has_list,
    [names], [properties]]`` (each property ``(None, size)``, or a list's ``(count type, item size)``); a header pcreg
    or Open3D cannot read is an :class:`InputError` naming the file."""
    with open(path, "rb") as fh:
        head = fh.read(MAX_HEADER_BYTES)
    if not head.startswith(b"ply"):
        raise InputError(f"{path}: no points could be read (not a PLY file: no 'ply' magic"
                         + ("; it starts with a UTF-8 byte-order mark, which a PLY cannot: save it without one)" if head.startswith(b"\xef\xbb\xbfply") else ")"))
    end = re.search(rb"^end_header\s*?$", head, re.MULTILINE)  # the line, not the word in a comment
    if end is None:
        raise InputError(f"{path}: PLY header without end_header")
    i = end.start()
    j = head.find(b"\n", i)
    if j < 0:
        raise InputError(f"{path}: truncated PLY header")
    longest = max(len(line) for line in head[:i].split(b"\n"))
    if longest > MAX_PLY_LINE:  # Open3D's reader (RPly) copies a header line into 1,024 bytes: it would abort
        raise InputError(f"{path}: a PLY header line of {longest} bytes (at most {MAX_PLY_LINE} are read)")
    fmt = None
    elements: list[list] = []
    for raw in head[:i].decode("ascii", "replace").splitlines():
        t = raw.split()
        if not t:
            continue
        if t[0] == "format" and len(t) >= 2:
            fmt = t[1]
        elif t[0] == "element" and len(t) == 3:
            try:
                elements.append([t[1], header_int(t[2]), [], False, [], []])
            except ValueError:
                raise InputError(f"{path}: bad PLY element line {raw.strip()!r}") from None
            if elements[-1][1] < 0:
                raise InputError(f"{path}: negative PLY element count")
        elif t[0] == "property" and elements:
            if len(t) >= 2 and t[1] == "list":
                if not (len(t) == 5 and t[2] in _PLY_SIZES and t[3] in _PLY_SIZES):  # RPly reads no other
                    raise InputError(f"{path}: bad PLY property line {raw.strip()[:80]!r} (a list of a count type and an "
                                     f"item type of {', '.join(_PLY_SIZES)}, and a name)")
                elements[-1][3] = True
                elements[-1][5].append((t[2], _PLY_SIZES[t[3]]))
            elif len(t) >= 3 and t[1] in _PLY_SIZES:
                elements[-1][2].append(_PLY_SIZES[t[1]])
                elements[-1][4].append(t[2])
                elements[-1][5].append((None, _PLY_SIZES[t[1]]))
            else:
                raise InputError(f"{path}: bad PLY property line {raw.strip()!r}")
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise InputError(f"{path}: unknown PLY format {fmt!r}")
    rply = end.start() + len(b"end_header") + (2 if head.startswith(b"ply\r\n") else 1)
    if fmt != "ascii" and rply != j + 1:  # RPly's data starts one byte after end_header (two after a first ply\r\n)
        ending = head[end.start() + len(b"end_header"):j + 1].decode("ascii", "replace")
        raise InputError(f"{path}: its end_header line ends in {ending!r}, its first line in "
                         f"{head[3:head.find(bytes([10])) + 1].decode('ascii', 'replace')!r}: Open3D's reader takes "
                         "them to end alike and would read the binary data from the wrong byte (end every header "
                         "line alike, without trailing blanks)")
    return fmt, elements, j + 1


def _ply_check(path: Path, size: int, limit: int) -> int:
    fmt, elements, body_start = _ply_header(path)
    vertex = next((e for e in elements if e[0] == "vertex"), None)
    if vertex is None or vertex[1] == 0:
        raise InputError(f"{path}: no vertices in the PLY header")
    if len(counts := [e[1] for e in elements if e[0] == "vertex"]) > 1:  # a reader takes the first alone
        raise InputError(f"{path}: the PLY header declares {len(counts)} vertex elements ({', '.join(map(str, counts))} points): a reader takes the first alone; write them as one")
    missing = [c for c in "xyz" if c not in vertex[4]]
    if missing:  # Open3D would fill them with whatever its memory held
        raise InputError(f"{path}: PLY vertices without the {', '.join(missing)} propert{'y' if len(missing) == 1 else 'ies'} (x, y and z are needed)")
    twice = sorted({name for name in vertex[4] if vertex[4].count(name) > 1})
    if twice:  # which one a reader takes is its own choice
        raise InputError(f"{path}: PLY vertices declare the {', '.join(twice)} propert{'y' if len(twice) == 1 else 'ies'} twice")
    for axes in (("x", "y", "z"), ("nx", "ny", "nz")):
        at = [vertex[4].index(a) for a in axes if a in vertex[4]]
        if len(at) == 3 and at[2] < max(at[:2]):  # Open3D moves to the next point after z (nz): the rest shifts
            raise InputError(f"{path}: its vertex properties {', '.join(axes)} come in the order "
                             f"{', '.join(sorted(axes, key=lambda a: vertex[4].index(a)))}: Open3D's reader, which "
                             f"reads PLY, takes {axes[2]} for the last of them and fails on this order (write "
                             f"{axes[2]} after {axes[0]} and {axes[1]})")
    n = vertex[1]
    check_point_count(n, str(path), limit=limit)
    if fmt == "ascii":
        _ply_ascii_body(path, body_start, elements, vertex)
        return n
    need = 0
    for e in elements:
        rec = sum(e[2]) + (1 if e[3] else 0)  # a list property takes at least its count byte
        need += e[1] * rec
        if e is vertex:
            break
    have = size - body_start
    if have < need:
        got = max(0, have) // max(1, sum(vertex[2]))
        raise InputError(f"{path}: truncated PLY: the header declares {n} vertices ({need} bytes), the file holds {have} bytes (about {min(got, n)} vertices)")
    end = _ply_body_end(path, body_start, size, elements, fmt)
    if end is not None and size - end >= sum(vertex[2]):  # a count that lies low: the rest would be read as what follows
        raise InputError(f"{path}: the PLY header declares {n} vertices, and its elements end {size - end} bytes before "
                         "the file does (more vertices than declared?)")
    if end is None or end > size:
        raise InputError(f"{path}: truncated or damaged PLY: the header declares {n} vertices ({need} bytes) and "
                         f"{', '.join(f'{e[1]} {e[0]}' for e in elements if e is not vertex and e[1]) or 'nothing'} after "
                         f"them, which the file's {have} bytes do not hold")
    return n


def _uniform_lists(data, at: int, size: int, records: int, props: list, count_type: str) -> int | None:
    """Where ``records`` records of ``props`` from ``at`` end when the element has one list property and every
    record's list is as long as the first's (a mesh of triangles), read at once; else None (walked one at a time)."""
    lists = [k for k, (c, _) in enumerate(props) if c is not None]
    if len(lists) != 1 or records == 0:
        return None
    k = lists[0]
    before = sum(item for _, item in props[:k])
    width = struct.calcsize(count_type)
    if at + before + width > size:
        return None
    first = struct.unpack_from(count_type, data, at + before)[0]
    record = sum(item for _, item in props[:k] + props[k + 1:]) + width + max(first, 0) * props[k][1]
    if first < 0 or at + records * record > size:
        return None
    rows = np.frombuffer(data, np.uint8, records * record, at).reshape(records, record)
    found = rows[:, before:before + width].copy().view(np.dtype(count_type)).ravel()
    return at + records * record if bool((found == first).all()) else None


#: The most records of elements with list properties (a mesh's faces) whose lengths are walked, one at a time.
MAX_WALKED = 2_000_000


def _ply_body_end(path: Path, start: int, size: int, elements: list[list], fmt: str) -> int | None:
    """Where a binary PLY's elements end, from ``start``, as a reader walks them: fixed records by their sizes, and
    records with list properties (a mesh's faces) by the counts the file holds (up to :data:`MAX_WALKED` records
    of them; more are taken to end with the file, and so are lists of a count type pcreg does not know). None when a
    list's count is negative or runs past the file's ``size``."""
    at, walked = start, 0
    order = "<" if fmt == "binary_little_endian" else ">"
    counts = {"char": "b", "int8": "b", "uchar": "B", "uint8": "B", "short": "h", "int16": "h", "ushort": "H",
              "uint16": "H", "int": "i", "int32": "i", "uint": "I", "uint32": "I"}
    with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
        for e in elements:
            props = e[5]
            if not e[3]:
                at += e[1] * sum(size_ for _, size_ in props)
                continue
            if any(c is not None and c not in counts for c, _ in props):
                return size
            uniform = _uniform_lists(data, at, size, e[1], props, order + counts[next(c for c, _ in props if c)])
            if uniform is not None:  # every record's list of one length (a mesh of triangles): at once
                at = uniform
                continue
            walked += e[1]
            if walked > MAX_WALKED:
                return size
            for _ in range(e[1]):
                for kind, item in props:
                    if kind is None:
                        at += item
                        continue
                    if at + _PLY_SIZES[kind] > size:
                        return None
                    k = struct.unpack_from(order + counts[kind], data, at)[0]
                    if k < 0:
                        return None
                    at += _PLY_SIZES[kind] + k * item
                    if at > size:
                        return None
    return at


def _ply_ascii_body(path: Path, body_start: int, elements: list[list], vertex: list) -> None:
    """An ASCII PLY's lines against its header, read once: as many as its elements declare, and each vertex line
    of scalar properties as many numbers as it has properties."""
    n = vertex[1]
    total = sum(e[1] for e in elements)
    before = 0
    for e in elements:
        if e is vertex:
            break
        before += e[1]
    fields = None if vertex[3] else len(vertex[2])  # a vertex of scalar properties: each line holds as many numbers
    lines, bad = _scan_rows(path, body_start, stop=total + 1, rows=(before, before + n), fields=fields)
    if lines > total:  # a count that lies low: Open3D would read the first n rows and drop the rest
        raise InputError(f"{path}: the PLY header declares {total} data lines ({n} vertices), the file holds more")
    if lines < before + n:
        raise InputError(f"{path}: truncated PLY: the header declares {n} vertices, the file holds "
                         f"{max(0, lines - before)}")
    if bad is not None:
        raise _row_error(path, bad, fields or 0, "vertex")


#: One number as an ASCII point cloud writes it (what C's ``strtod`` reads whole): digits, a point, an exponent,
#: or nan / inf; not ``1,0`` (a decimal comma, which a reader takes for two numbers or one and junk), not ``1_0``.
_ASCII_NUMBER = rb"[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|(?i:nan(?:\([0-9a-z_]*\))?|inf(?:inity)?))"


def _row_pattern(numbers: int) -> re.Pattern[bytes]:
    """A data line of ``numbers`` numbers (:data:`_ASCII_NUMBER`) between white space, no more and no fewer (a
    counted repeat: its size does not follow the header's COUNT, which may declare a billion)."""
    return re.compile(rb"\s*" + _ASCII_NUMBER + rb"(?:\s+" + _ASCII_NUMBER + rb"){%d}\s*" % (numbers - 1))


#: Classes of a data line's bytes in the vectorised check of plain numbers (:func:`_plain_rows`).
_DIGIT, _WS, _POINT, _SIGN, _EXP, _LETTER, _OTHER = 0, 1, 2, 3, 4, 5, 6
_BYTE_CLASS = np.full(256, _OTHER, np.uint8)
_BYTE_CLASS[list(b" \t\n\r\x0b\x0c")] = _WS  # what ``bytes.strip`` and the pattern's \s take for white space
_BYTE_CLASS[list(b"0123456789")] = _DIGIT
_BYTE_CLASS[ord(".")] = _POINT
_BYTE_CLASS[list(b"+-")] = _SIGN
_BYTE_CLASS[list(b"eE")] = _EXP
_BYTE_CLASS[list(b"nNaAiIfFtTyY")] = _LETTER  # of nan, inf and infinity
#: Bytes read and checked at a time (whole lines: a longer line is read whole, and its block checked line by line).
_SCAN_BYTES = 1 << 20


def _scan_rows(path: Path, start: int, *, stop: int, rows: tuple[int, int],
               fields: int | None) -> tuple[int, tuple[int, bytes] | None]:
    """One pass over the lines from byte ``start``: how many are not blank (at most ``stop`` counted), and the
    first of the non-blank lines numbered ``rows[0]`` to ``rows[1] - 1`` (from 0) that does not hold ``fields``
    numbers (:func:`_row_pattern`), as (its number among those rows from 1, its bytes), or None (``fields``
    None: not checked). The lines are checked a block at a time (:func:`_plain_rows`); the pattern reads only
    those that are not found plain numbers (``nan(...)``, damage), and decides."""
    numbers = max(1, fields or 0)  # as the line's pattern counted them: fields 0 took one number
    count = 0
    bad = None
    with open(path, "rb") as fh:
        fits = 2 * numbers - 1 <= os.fstat(fh.fileno()).st_size - start  # else no line can hold them
        row = _row_pattern(numbers) if fits else None
        fh.seek(start)
        for buf in _blocks_of_lines(fh):
            ends, filled, plain = _plain_rows(buf, numbers)
            lines = np.flatnonzero(filled)[:stop - count]  # the block's non-blank lines, count + 0, 1, ...
            if fields is not None and bad is None:
                lo, hi = max(0, rows[0] - count), max(0, rows[1] - count)
                doubt = np.flatnonzero(~plain[lines[lo:hi]])  # the lines (of those checked) the pattern decides
                at = lines[lo:hi][doubt]
                firsts, lasts = np.where(at > 0, ends[at - 1] + 1, 0).tolist(), (ends[at] + 1).tolist()
                failed = (k for k, (first, last) in enumerate(zip(firsts, lasts))
                          if row is None or row.fullmatch(buf, first, last) is None)
                k = next(failed, None)
                if k is not None:
                    bad = (count + lo + int(doubt[k]) - rows[0] + 1, buf[firsts[k]:lasts[k]])
            count += len(lines)
            if count >= stop:
                break
    return count, bad


def _blocks_of_lines(fh) -> Iterator[bytes]:
    """The rest of ``fh`` in blocks of whole lines of about :data:`_SCAN_BYTES` each (after each newline, as a
    file's lines are split), the last one as the file ends."""
    pieces: list[bytes] = []
    while block := fh.read(_SCAN_BYTES):
        cut = block.rfind(b"\n") + 1
        if cut == 0:  # inside a line longer than a block
            pieces.append(block)
            continue
        yield b"".join(pieces) + block[:cut]
        pieces = [block[cut:]]
    if any(pieces):
        yield b"".join(pieces)


def _plain_rows(buf: bytes, numbers: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where each line of ``buf`` ends (its newline, or the last byte), which lines are not blank, and which are
    certainly ``numbers`` plain numbers: :data:`_ASCII_NUMBER` but ``nan(...)``, each byte judged in its place
    (:func:`_misplaced`). A line not found plain may still be numbers: the pattern decides. A block longer than
    two of :data:`_SCAN_BYTES` (a line longer than one) is left to the pattern, line by line: its arrays would
    take several times its size."""
    if len(buf) > 2 * _SCAN_BYTES:
        ends = np.array([m.start() for m in re.finditer(rb"\n", buf)] + ([] if buf.endswith(b"\n") else [len(buf) - 1]),
                        dtype=np.int64)
        filled = np.array([bool(buf[e0 + 1:e1 + 1].strip()) for e0, e1 in zip(np.r_[-1, ends[:-1]], ends)], dtype=bool)
        return ends, filled, np.zeros(len(ends), bool)
    raw = np.frombuffer(buf, np.uint8)
    c = np.take(_BYTE_CLASS, raw)
    white = np.flatnonzero(c == _WS)
    ends = white[raw[white] == 10]
    if not buf.endswith(b"\n"):
        ends = np.append(ends, len(buf) - 1)
    begins = np.r_[-1, white] + 1  # the first byte of each number (or of anything else)
    begins = begins[begins < len(c)]
    begins = begins[c[begins] != _WS]
    tokens = np.diff(np.searchsorted(begins, ends, side="right"), prepend=0)
    damaged = np.logical_or.reduceat(c == _OTHER, np.r_[0, ends[:-1] + 1])  # a byte of no number
    if not damaged.all():  # (every line of a block of nan(ind) has one)
        damaged[np.searchsorted(ends, _misplaced(raw, c))] = True
    return ends, tokens > 0, ~damaged & (tokens == numbers)


def _misplaced(raw: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Where a sign, point, exponent or letter of ``raw`` (classes ``c``) stands where no number
    (:data:`_ASCII_NUMBER`) has it: a sign first or after the exponent, before a digit (or a point or a word,
    first); a point beside a digit; an exponent after a digit (or a point after one), before a digit or a sign;
    one point and one exponent a number, the point first; a word of letters nan, inf or infinity, alone or after
    a sign."""
    def near(at: np.ndarray, k: int) -> np.ndarray:  # the class of the byte k after each of ``at`` (white off raw)
        q = at + k
        out = np.full(len(at), _WS, np.uint8)
        inside = (q >= 0) & (q < len(c))
        out[inside] = c[q[inside]]
        return out

    marks = np.flatnonzero(c > _WS)
    kinds = c[marks]
    sign, point, exp, letter = (marks[kinds == k] for k in (_SIGN, _POINT, _EXP, _LETTER))
    before, after = near(sign, -1), near(sign, 1)
    first = (before == _WS) & ((after == _DIGIT) | (after == _POINT) | (after == _LETTER))
    wrong = [sign[~(first | ((before == _EXP) & (after == _DIGIT)))],
             point[(near(point, -1) != _DIGIT) & (near(point, 1) != _DIGIT)]]
    before, after = near(exp, -1), near(exp, 1)
    mantissa = (before == _DIGIT) | ((before == _POINT) & (near(exp, -2) == _DIGIT))
    wrong.append(exp[~mantissa | ((after != _DIGIT) & (after != _SIGN))])
    spaces = np.cumsum(c == _WS, dtype=np.int32)  # bytes p < q, not white, are in one number iff spaces[p] == spaces[q]
    in_point, in_exp = spaces[point], spaces[exp]
    for at, number in ((point, in_point), (exp, in_exp)):  # a second point, or a second exponent, in one number
        wrong.append(at[1:][number[1:] == number[:-1]])
    last = np.searchsorted(exp, point) - 1  # a point after its number's exponent
    wrong.append(point[last >= 0][in_point[last >= 0] == in_exp[last[last >= 0]]])
    starts, stops = letter[near(letter, -1) != _LETTER], letter[near(letter, 1) != _LETTER]  # words of letters
    word = np.zeros(len(starts), bool)
    for spelt in (b"nan", b"inf", b"infinity"):
        match = stops - starts + 1 == len(spelt)
        for k, byte in enumerate(spelt):  # (| 0x20: in lower case)
            match &= (raw[np.minimum(starts + k, len(raw) - 1)] | 0x20) == byte
        word |= match
    placed = ((near(starts, -1) == _WS) | (near(starts, -1) == _SIGN)) & (near(stops, 1) == _WS)
    wrong.append(starts[~(word & placed)])
    return np.concatenate(wrong)


def _row_error(path: Path, bad: tuple[int, bytes], fields: int, what: str) -> InputError:
    """The refusal of a data line that is not ``fields`` numbers (Open3D reads one short line as the next one's
    start, or fills a point with what its memory held, a junk line as a point at the origin)."""
    number, line = bad
    text = line.decode("ascii", "replace").strip()
    if not line.endswith(b"\n"):  # the file ends inside this line
        return InputError(f"{path}: truncated: its last line ({text[:40]!r}) is cut short")
    return InputError(f"{path}: {what} line {number} ({text[:40]!r}) is not {fields} numbers, as the header declares")


def _holds_data(path: Path, start: int) -> bool:
    """Whether ``path`` holds a byte other than zero from ``start`` on (PCL's binary writer pads a PCD with zeros
    to a memory page: not points)."""
    with open(path, "rb") as fh:
        fh.seek(start)
        while chunk := fh.read(1 << 20):
            if chunk.count(0) != len(chunk):
                return True
    return False


#: The keywords of a PCD header, in the order PCL writes them. PCL's and Open3D's readers match them in upper
#: case only: a line that spells one otherwise is skipped, so that ``data ascii`` never ends the header.
PCD_KEYWORDS = ("VERSION", "FIELDS", "COLUMNS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")


@dataclass(frozen=True)
class PcdHeader:
    """What a PCD's header declares: its ``points``, the ``fields`` with their ``sizes``, ``types`` (upper
    case) and ``counts``, the ``data`` kind (``ascii``, ``binary`` or ``binary_compressed``), where its data
    starts (``start``, bytes) and the order of its keyword lines (``keywords``)."""

    points: int
    fields: tuple[str, ...]
    sizes: tuple[int, ...]
    types: tuple[str, ...]
    counts: tuple[int, ...]
    data: str
    start: int
    keywords: tuple[str, ...]

    def column(self, name: str) -> int | None:
        """The first number of field ``name`` among an ASCII line's numbers, or None (no such field)."""
        if name not in self.fields:
            return None
        return sum(self.counts[:self.fields.index(name)])


def _pcd_lines(path: Path) -> tuple[dict[str, list[str]], list[str], str | None, int]:
    """The keyword lines of a PCD's header (``{keyword: words}``, the keywords in order), its DATA kind as
    written (None: no DATA line) and where its data starts."""
    with open(path, "rb") as fh:
        head = fh.read(1 << 16)
    fields: dict[str, list[str]] = {}
    order: list[str] = []
    pos = 0
    for line in head.split(b"\n"):
        pos += len(line) + 1
        text = line.decode("ascii", "replace").strip()
        if not text or text.startswith("#"):
            continue
        t = text.split()
        if t[0] != t[0].upper() and t[0].upper() in PCD_KEYWORDS:
            raise InputError(f"{path}: PCD header line {text[:40]!r}: its keyword must be upper case, "
                             f"{t[0].upper()} (PCL's and Open3D's readers pass over it)")
        if t[0] in fields:  # which line a reader takes is its own choice
            raise InputError(f"{path}: its PCD header has two {t[0]} lines")
        fields[t[0]] = t[1:]
        order.append(t[0])
        if t[0] == "DATA":
            return fields, order, t[1] if len(t) > 1 else "", pos
    return fields, order, None, pos


def pcd_header(path: Path) -> PcdHeader:
    """The header of the PCD at ``path``, its numbers parsed and consistent, or an :class:`InputError` naming
    the file (no DATA line, numbers that are not, SIZE and COUNT of other lengths, a TYPE of no size)."""
    fields, order, data_kind, pos = _pcd_lines(path)
    if data_kind is None:
        raise InputError(f"{path}: PCD header without a DATA line")
    try:
        n = header_int(fields["POINTS"][0]) if "POINTS" in fields else \
            header_int(fields["WIDTH"][0]) * header_int(fields["HEIGHT"][0])
        sizes = [header_int(s) for s in fields["SIZE"]]
        counts = [header_int(c) for c in fields.get("COUNT", ["1"] * len(sizes))]
        grid = (header_int(fields["WIDTH"][0]), header_int(fields["HEIGHT"][0])) if "WIDTH" in fields and "HEIGHT" in fields else None
    except (KeyError, ValueError, IndexError, TypeError):
        raise InputError(f"{path}: damaged PCD header (POINTS, SIZE, COUNT)") from None
    if n <= 0:
        raise InputError(f"{path}: no points in the PCD header")
    if grid is not None and grid[0] * grid[1] != n:  # PCL refuses it; Open3D takes the count of the later line
        raise InputError(f"{path}: damaged PCD header: WIDTH {grid[0]} x HEIGHT {grid[1]} is not its POINTS {n}")
    if len(counts) != len(sizes) or any(s <= 0 for s in sizes) or any(c <= 0 for c in counts):
        raise InputError(f"{path}: damaged PCD header (SIZE and COUNT disagree)")
    types = [t.upper() for t in fields.get("TYPE", ["F"] * len(sizes))]
    if len(types) != len(sizes) or any(t not in "FIU" or len(t) != 1 for t in types) \
            or any(s not in ((4, 8) if t == "F" else (1, 2, 4, 8)) for s, t in zip(sizes, types)):
        raise InputError(f"{path}: damaged PCD header (TYPE {' '.join(types)} with SIZE "
                         f"{' '.join(map(str, sizes))}: F takes 4 or 8 bytes, I and U 1, 2, 4 or 8)")
    if data_kind not in ("ascii", "binary", "binary_compressed"):  # PCL and Open3D read any other as ASCII
        raise InputError(f"{path}: unknown PCD DATA kind {data_kind!r} (ascii, binary or binary_compressed)")
    names = fields.get("FIELDS", fields.get("COLUMNS", []))  # COLUMNS: the word of PCD v0.5 (PCL reads both)
    if len(names) != len(sizes):  # PCL and Open3D refuse it
        raise InputError(f"{path}: damaged PCD header (FIELDS names {len(names)} fields, SIZE gives {len(sizes)})")
    twice = sorted({f for f in names if names.count(f) > 1 and f != "_"})  # "_": PCL's padding, as often as it pads
    if twice:  # which one a reader takes is its own choice (pcreg's ASCII reader the first, Open3D's the last)
        raise InputError(f"{path}: its PCD header names the field{'s' * (len(twice) > 1)} {', '.join(twice)} twice")
    return PcdHeader(n, tuple(names), tuple(sizes), tuple(types), tuple(counts), data_kind, pos,
                     tuple(order))


def _pcd_check(path: Path, size: int, limit: int) -> int:
    h = pcd_header(path)
    n, sizes, counts, data_kind, pos = h.points, h.sizes, h.counts, h.data, h.start
    check_point_count(n, str(path), limit=limit)
    point_bytes = sum(s * c for s, c in zip(sizes, counts))
    have = size - pos
    coords = [sizes[i] for i, f in enumerate(h.fields[:len(sizes)]) if f.lower() in ("x", "y", "z")]
    if data_kind in ("binary", "binary_compressed") and 8 in coords:
        # Open3D reads 8-byte (double) coordinates of a binary PCD as zeros, without a word
        raise InputError(f"{path}: a binary PCD whose x, y, z are 8-byte numbers is not read correctly "
                         "(its points come out as zeros); save it with 4-byte floats, as ASCII PCD, PLY or .npy")
    late = data_kind != "ascii" and "COUNT" in h.keywords and h.keywords.index("COUNT") < h.keywords.index("SIZE")
    if late and max(counts) > 1:  # Open3D places the fields by the SIZE line alone when it comes last
        raise InputError(f"{path}: its COUNT line comes before SIZE, and a field holds {max(counts)} numbers: "
                         "Open3D's reader would take the fields' bytes from the wrong places (write SIZE first, "
                         "as PCL does)")
    if data_kind == "ascii":
        lines, bad = _scan_rows(path, pos, stop=n + 1, rows=(0, n), fields=sum(counts))
        if bad is not None:
            raise _row_error(path, bad, sum(counts), "data")
        if lines < n:
            raise InputError(f"{path}: truncated PCD: the header declares {n} points, the file holds {lines}")
        if lines > n:  # a count that lies low: Open3D would read the first n and drop the rest
            raise InputError(f"{path}: the PCD header declares {n} points, the file holds more")
    elif data_kind == "binary":
        if have < n * point_bytes:
            raise InputError(f"{path}: truncated PCD: the header declares {n} points ({n * point_bytes} bytes), "
                             f"the file holds {have} bytes")
        if have >= (n + 1) * point_bytes and _holds_data(path, pos + n * point_bytes):  # a count that lies low
            raise InputError(f"{path}: the PCD header declares {n} points ({n * point_bytes} bytes), the file holds "
                             f"{have} bytes (more points than declared?)")
    elif data_kind == "binary_compressed":
        with open(path, "rb") as fh:
            fh.seek(pos)
            sz = fh.read(8)
        if len(sz) < 8:
            raise InputError(f"{path}: truncated PCD (no compressed block)")
        comp, raw = struct.unpack("<II", sz)
        if raw != n * point_bytes or have - 8 < comp:
            raise InputError(f"{path}: truncated or damaged compressed PCD (block of {comp} bytes, "
                             f"{have - 8} present; {raw} bytes unpacked for {n * point_bytes} expected)")
        if raw > LZF_MOST_UNPACKED * comp:  # Open3D reserves the points and the unpacked block before unpacking
            raise InputError(f"{path}: damaged compressed PCD: its block of {comp} bytes cannot unpack to the {raw} "
                             f"bytes ({n} points) its header declares (LZF unpacks a byte to {LZF_MOST_UNPACKED} at "
                             "most)")
    return n


#: What numpy raises on a damaged .npy header: its parser reads the header as a Python literal, and
#: a header it cannot parse is tokenized again for Python 2's syntax (``tokenize.TokenError``).
NPY_HEADER_ERRORS: tuple[type[BaseException], ...] = (ValueError, OSError, SyntaxError, TypeError, struct.error,
                                                      UnicodeDecodeError, tokenize.TokenError)


def check_npy_file(path: Path, limit: int) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype from a .npy header, with the file's size checked against them."""
    try:
        with open(path, "rb") as fh:
            version = np.lib.format.read_magic(fh)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(fh, max_header_size=10000)
            elif version in ((2, 0), (3, 0)):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(fh, max_header_size=10000)
            else:
                raise ValueError(f"unsupported .npy version {version}")
            start = fh.tell()
    except NPY_HEADER_ERRORS as exc:
        raise InputError(f"{path}: not a numpy array file ({str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__})") from None
    if dtype.hasobject or dtype.kind not in "iuf" or dtype.fields is not None or dtype.subdtype is not None:
        what = " (true/false values: a mask, not coordinates)" if dtype.kind == "b" else ""
        raise InputError(f"{path}: points must be a numeric array, got dtype {dtype}{what}")
    if any(int(s) < 0 for s in shape):
        raise InputError(f"{path}: bad shape {shape}")
    count = math.prod(int(s) for s in shape)
    if len(shape) == 2:
        check_point_count(int(shape[0]), str(path), limit=limit)
    if count > 3 * limit:
        raise InputError(f"{path}: {count} values exceed the limit (raise --max-pixels or PCREG_MAX_PIXELS)")
    size = path.stat().st_size
    if size - start < count * dtype.itemsize:
        raise InputError(f"{path}: truncated .npy: the header declares {shape} {dtype} "
                         f"({count * dtype.itemsize} bytes), the file holds {size - start}")
    if size - start > count * dtype.itemsize:  # numpy reads what the header declares and leaves the rest unread
        raise InputError(f"{path}: the .npy header declares {shape} {dtype} ({count * dtype.itemsize} bytes), the "
                         f"file holds {size - start} bytes after it (more points than declared, or arrays saved one "
                         "after another into one file?)")
    return tuple(int(s) for s in shape), dtype


def check_cloud_file(path: str | os.PathLike, *, limit: int | None = None) -> Path:
    """A regular point-cloud file whose header's point count is within the limit and whose data is
    all there (PLY and PCD, ASCII and binary). Other text formats (.xyz, .pts) are only size-bounded."""
    p = check_regular_file(path, what="point cloud")
    lim = max_pixels(limit)
    size = p.stat().st_size
    if size == 0:
        raise InputError(f"{p}: empty file")
    if size > max_file_bytes(lim) * 4:  # ASCII formats spend up to ~100 bytes a point
        raise InputError(f"{p}: {size / 2**20:.0f} MiB exceeds the limit (raise --max-pixels or PCREG_MAX_PIXELS)")
    suffix = p.suffix.lower()
    try:
        if suffix == ".ply":
            _ply_check(p, size, lim)
        elif suffix == ".pcd":
            _pcd_check(p, size, lim)
    except OSError as exc:
        raise InputError(f"{p}: cannot read point cloud ({exc.strerror or exc})") from None
    return p
