"""What the fuzz suites of files share: hypothesis's settings (derandomized, no database), a bound on how long one
reader may run, the contract every reader is held to (a valid result, or one line of PcregError naming the file),
and the mutations of bytes and of text that turn a valid file into a damaged one."""

from __future__ import annotations

import contextlib
import os
import re
import signal

from hypothesis import HealthCheck, Phase, event, settings
from hypothesis import strategies as st

from pcreg.errors import PcregError

_COMMON = dict(deadline=None, derandomize=True, database=None,  # no explain phase: it reruns a failure for minutes
               phases=[Phase.explicit, Phase.reuse, Phase.generate, Phase.target, Phase.shrink],
               suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                      HealthCheck.data_too_large, HealthCheck.large_base_example])
#: The quick suite's examples of a reader.
FUZZ = settings(max_examples=25, **_COMMON)
#: The slow suite's, of the same readers (``PCREG_FUZZ_EXAMPLES`` sets another number, to look further).
FUZZ_MORE = settings(max_examples=int(os.environ.get("PCREG_FUZZ_EXAMPLES", "300")), **_COMMON)
HANG_SECONDS = 20


class Hang(BaseException):
    """A reader ran too long: a BaseException, so that no ``except Exception`` of the reader's (the command line's
    report of a bug among them) takes it for an error of its own."""


@contextlib.contextmanager
def bounded(seconds: int = HANG_SECONDS):
    """Raise :class:`Hang` in the body when it runs past ``seconds``."""
    def alarm(signum, frame):
        raise Hang(f"a reader ran past {seconds} s")

    previous = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def refused_in_a_line(exc: BaseException, *names: str) -> None:
    """``exc`` is a PcregError whose line on the command line (its text, white space joined, at most 500 characters)
    names one of ``names`` (the file, or the archive holding it)."""
    from pcreg.cli import _one_line

    assert isinstance(exc, PcregError), repr(exc)
    said = _one_line(exc)
    assert str(exc).strip() and any(n in said for n in names), f"{said!r} names none of {names}"


@contextlib.contextmanager
def held_to_contract(*names: str):
    """The body returns (its result is the caller's to check) or raises a PcregError of one line naming one of
    ``names``; anything else, or a body past :data:`HANG_SECONDS`, fails the example. Which of the two it was is
    an event of hypothesis's statistics (``--hypothesis-show-statistics``): how far the examples reach."""
    with bounded():
        try:
            yield
        except PcregError as exc:
            refused_in_a_line(exc, *names)
            event("refused")
        else:
            event("read")


@st.composite
def mutated_bytes(draw, seed: bytes) -> bytes:
    """``seed`` with 1 to 4 of: a bit flipped, cut short, bytes inserted or overwritten, a run of zeros, a part of
    it repeated."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, 4))):
        if not data:
            break
        op = draw(st.sampled_from(["flip", "truncate", "insert", "overwrite", "zero_run", "duplicate"]))
        pos = draw(st.integers(0, len(data) - 1))
        if op == "flip":
            data[pos] ^= 1 << draw(st.integers(0, 7))
        elif op == "truncate":
            del data[pos:]
        elif op == "insert":
            data[pos:pos] = draw(st.binary(min_size=1, max_size=16))
        elif op == "overwrite":
            chunk = draw(st.binary(min_size=1, max_size=16))
            data[pos:pos + len(chunk)] = chunk
        elif op == "zero_run":
            data[pos:pos + draw(st.integers(1, 64))] = b"\0" * 8
        else:
            end = draw(st.integers(pos, min(len(data), pos + 256)))
            at = draw(st.integers(0, len(data)))
            data[at:at] = data[pos:end]
    return bytes(data)


@st.composite
def header_then_random(draw, seed: bytes, head: int = 128) -> bytes:
    """The first bytes of ``seed`` (up to ``head``), then random bytes."""
    return seed[:draw(st.integers(1, min(head, len(seed))))] + draw(st.binary(max_size=256))


#: Characters a text mutation inserts: separators and digits of the formats, line breaks of every kind, a BOM,
#: a NUL, a lone surrogate's neighbours, letters of other scripts, and any character hypothesis makes.
_ODD = [":", ",", "#", "{", "}", "[", "]", '"', "\\", " ", "\t", "\n", "\r", "\r\n", "\x85", "\u2028", "\u2029",
        "\v", "\f", "\x1c", "\ufeff", "\0", "\u0660", "\uff11", "é", "e\u0301", "\U0001F600", "\u202e"]
#: What a mutation puts in a number's place: out of range, fractional, in other digits (Arabic-Indic, superscript:
#: ``str.isdigit`` takes both, ``int`` only the first), longer than ``int`` converts (4300 digits).
ODD_NUMBERS = ["-1", "256", "99999999999999999999999", "9" * 5000, "1e309", "1.5", "-0", "0x10", "1_0", "٣", "²", ""]
_NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


@st.composite
def mutated_text(draw, seed: str, sep: str = ":") -> str:
    """``seed`` (a text of lines of ``sep``-separated fields) with 1 to 3 of: a field dropped, a separator added,
    an odd character inserted, a number made huge, negative, fractional or another, a line dropped, repeated or
    cut short."""
    text = seed
    for _ in range(draw(st.integers(1, 3))):
        lines = text.split("\n")
        i = draw(st.integers(0, max(0, len(lines) - 1)))
        line = lines[i] if lines else ""
        op = draw(st.sampled_from(["drop_field", "add_sep", "insert", "number", "drop_line", "repeat_line",
                                   "cut_line", "unicode"]))
        if op == "drop_field" and sep in line:
            fields = line.split(sep)
            del fields[draw(st.integers(0, len(fields) - 1))]
            line = sep.join(fields)
        elif op == "add_sep":
            at = draw(st.integers(0, len(line)))
            line = line[:at] + sep + line[at:]
        elif op in ("insert", "unicode"):
            ch = draw(st.sampled_from(_ODD)) if op == "insert" else draw(st.text(min_size=1, max_size=3))
            at = draw(st.integers(0, len(line)))
            line = line[:at] + ch + line[at:]
        elif op == "number":
            found = list(_NUMBER.finditer(line))
            if found:
                m = found[draw(st.integers(0, len(found) - 1))]
                new = draw(st.sampled_from([*ODD_NUMBERS, str(draw(st.integers(-10**6, 10**6)))]))
                line = line[:m.start()] + new + line[m.end():]
        elif op == "drop_line" and lines:
            lines.pop(i)
            text = "\n".join(lines)
            continue
        elif op == "repeat_line" and lines:
            lines.insert(draw(st.integers(0, len(lines))), line)
            text = "\n".join(lines)
            continue
        elif op == "cut_line":
            line = line[:draw(st.integers(0, len(line)))]
        if lines:
            lines[i] = line
        else:
            lines = [line]
        text = "\n".join(lines)
    return text


#: Any JSON value, small: what a mutation of a JSON document puts in the place of a part.
json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.floats(allow_nan=False) | st.text(max_size=8)
    | st.sampled_from(ODD_NUMBERS),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=8)


def _parts(doc, at=()):
    """``(path, part)`` of every part of a JSON document, itself first."""
    yield at, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _parts(v, (*at, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _parts(v, (*at, i))


def _numeric(value) -> bool:
    return type(value) in (int, float) or (isinstance(value, str) and value.isdigit())


#: Which parts of a JSON document each mutation applies to: the path to a part, and the part.
_APPLIES = {"replace": lambda path, value: True, "drop": lambda path, value: bool(path),
            "add": lambda path, value: isinstance(value, dict), "number": lambda path, value: bool(path) and _numeric(value),
            "repeat": lambda path, value: isinstance(value, list) and bool(value),
            "rename": lambda path, value: bool(path) and isinstance(path[-1], str)}


@st.composite
def mutated_json(draw, doc):
    """A copy of the JSON document ``doc`` with 1 to 3 of: a part replaced by any JSON value, a key or an item
    dropped, a key added or renamed, a number made huge, negative or fractional (or a string of digits odd, as a
    frame's number), an item repeated; each applied to a part it fits."""
    import copy

    doc = copy.deepcopy(doc)
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(sorted(_APPLIES)))
        fits = [(path, value) for path, value in _parts(doc) if _APPLIES[op](path, value)]
        if not fits:
            continue
        path, value = draw(st.sampled_from(fits))
        if not path:
            doc = draw(json_values)
            continue
        parent = doc
        for k in path[:-1]:
            parent = parent[k]
        last = path[-1]
        if op == "replace":
            parent[last] = draw(json_values)
        elif op == "drop":
            del parent[last]
        elif op == "add":
            value[draw(st.text(max_size=8))] = draw(json_values)
        elif op == "number" and isinstance(value, str):  # a frame's number as a name
            parent[last] = draw(st.sampled_from(ODD_NUMBERS))
        elif op == "number":
            parent[last] = draw(st.sampled_from([-1, 0, 256, 2**64, 10**30, 1.5, -0.0, 1e308, True, str(value)]))
        elif op == "rename":  # a key renamed; a frame's number to an odd one
            parent[draw(st.sampled_from(ODD_NUMBERS) if last.isdigit() else st.text(max_size=8))] = parent.pop(last)
        else:
            value.insert(draw(st.integers(0, len(value))), copy.deepcopy(draw(st.sampled_from(value))))
    return doc
