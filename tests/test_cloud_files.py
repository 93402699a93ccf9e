"""pcreg.cloud_files: the checks a PLY or PCD passes before Open3D reads it. A damaged file is refused in one
line naming it before anything proportional to what its header declares is reserved; a sound file reads as
Open3D wrote it. (The many hostile files of every loader are in test_hostile.py.)"""

from __future__ import annotations

import re
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pcreg.cloud_files import LZF_MOST_UNPACKED, check_cloud_file
from pcreg.errors import InputError


def pcd_head(n: int, kind: str, *, fields: str = "x y z", size: str = "4 4 4", type_: str = "F F F",
             count: str = "1 1 1") -> bytes:
    return (f"# .PCD v0.7\nVERSION 0.7\nFIELDS {fields}\nSIZE {size}\nTYPE {type_}\nCOUNT {count}\nWIDTH {n}\n"
            f"HEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {kind}\n").encode()


def compressed(head: bytes, raw: int, block: bytes) -> bytes:
    """A binary_compressed PCD whose block of ``len(block)`` bytes declares ``raw`` bytes unpacked."""
    return head + struct.pack("<II", len(block), raw) + block


def _bombs(t):
    """A few hundred bytes declaring 50 million points (600 MB unpacked), and 1,000 points of 4 MB each."""
    (t / "bomb_points.pcd").write_bytes(compressed(pcd_head(50_000_000, "binary_compressed"), 600_000_000,
                                                   bytes(200)))
    head = pcd_head(1000, "binary_compressed", fields="x y z w", size="4 4 4 4", type_="F F F F",
                    count="1 1 1 1000000")
    (t / "bomb_count.pcd").write_bytes(compressed(head, 1000 * (12 + 4_000_000), bytes(200)))


@pytest.fixture
def clouds(tmp_path):
    _bombs(tmp_path)
    pts = np.random.default_rng(2).normal(size=(400, 3)).astype("<f4")
    (tmp_path / "ok.pcd").write_bytes(pcd_head(400, "binary") + pts.tobytes())
    return tmp_path


def _reader_not_reached(monkeypatch):
    import open3d as o3d

    def read(*args, **kwargs):
        raise AssertionError("the bomb reached Open3D's reader")

    monkeypatch.setattr(o3d.io, "read_point_cloud", read)


@pytest.mark.parametrize("name, declared", [("bomb_points.pcd", "600000000 bytes (50000000 points)"),
                                            ("bomb_count.pcd", "4000012000 bytes (1000 points)")])
def test_a_compressed_pcd_bomb_is_refused_before_open3d_reserves_it(clouds, monkeypatch, name, declared):
    """Open3D reserves the declared points and the unpacked block before it unpacks (1.7 and 3.8 GiB of
    address space for these files, std::bad_alloc under a memory limit): the block's own size refuses them."""
    from pcreg.implementations.crosscheck import load_cloud

    _reader_not_reached(monkeypatch)
    with pytest.raises(InputError, match=re.escape(f"block of 200 bytes cannot unpack to the {declared}")) as err:
        load_cloud(clouds / name)
    assert str(err.value).startswith(str(clouds / name)) and "\n" not in str(err.value)


def test_a_compressed_pcd_bomb_is_one_line_and_exit_2(clouds, capsys):
    from pcreg.cli import main

    rc = main(["crosscheck", str(clouds / "bomb_points.pcd"), str(clouds / "ok.pcd")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert "bomb_points.pcd: damaged compressed PCD" in err[0] and "Traceback" not in err[0]


@pytest.mark.parametrize("zeros", [False, True])
def test_compressed_pcds_open3d_writes_still_read(tmp_path, zeros):
    """Open3D's own compressed PCDs pass, all-zero points too: LZF's best ratio, just under the bound."""
    import open3d as o3d

    from pcreg.implementations.crosscheck import load_cloud

    n = 100_000 if zeros else 500
    pts = np.zeros((n, 3)) if zeros else np.random.default_rng(3).normal(size=(n, 3)) * 10
    path = tmp_path / "written.pcd"
    o3d.io.write_point_cloud(str(path), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)), compressed=True)
    data = path.read_bytes()
    comp, raw = struct.unpack("<II", data[data.index(b"binary_compressed\n") + 18:][:8])
    assert raw == 12 * n and (raw / comp > 80) == zeros  # zeros: near LZF_MOST_UNPACKED
    assert raw <= LZF_MOST_UNPACKED * comp
    assert check_cloud_file(path) == path
    if not zeros:  # (an all-zero cloud is a registration input pcreg refuses further on)
        np.testing.assert_array_equal(load_cloud(path), pts.astype(np.float32).astype(np.float64))


def ply_ascii(n: int, *, faces: int = 0, vertices: list[str] | None = None) -> bytes:
    """An ASCII PLY declaring ``n`` vertices and ``faces`` faces; ``vertices``: its vertex lines (n random ones)."""
    pts = np.random.default_rng(1).normal(size=(n, 3))
    lines = [f"{a:.5f} {b:.5f} {c:.5f}\n" for a, b, c in pts] if vertices is None else vertices
    head = (f"ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
            f"element face {faces}\nproperty list uchar int vertex_indices\nend_header\n")
    return (head + "".join(lines) + "3 0 1 2\n" * faces).encode()


def test_an_ascii_ply_is_read_once(tmp_path, monkeypatch):
    """Its header, then its lines once: counted and checked in one pass (they were read twice)."""
    import builtins

    import pcreg.cloud_files as cloud_files

    path = tmp_path / "ascii.ply"
    path.write_bytes(ply_ascii(300, faces=2))
    opened = []

    def counting_open(file, *args, **kwargs):
        opened.append(Path(file))
        return builtins.open(file, *args, **kwargs)

    monkeypatch.setattr(cloud_files, "open", counting_open, raising=False)
    assert check_cloud_file(path) == path
    assert opened == [path, path]  # the header, the lines


GOOD = ["1 2 3\n"] * 5
BAD = ["1 2 3\n", "1 2 3 7\n", "1 2 3\n", "1 2 3\n", "1 2 3\n"]


@pytest.mark.parametrize("name, data, message", [
    ("sound", ply_ascii(5, faces=2, vertices=GOOD), None),
    ("a vertex line of four numbers", ply_ascii(5, faces=2, vertices=BAD), "vertex line 2 ('1 2 3 7') is not 3 numbers"),
    ("that, and more lines than declared", ply_ascii(5, faces=2, vertices=BAD + ["1 2 3\n"]),
     "the PLY header declares 7 data lines (5 vertices), the file holds more"),
    ("that, and too few lines", ply_ascii(5, faces=0, vertices=BAD[:4]),
     "truncated PLY: the header declares 5 vertices, the file holds 4"),
    ("a face line where a vertex was", ply_ascii(5, faces=2, vertices=GOOD[:4] + ["3 0 1 2\n"]),
     "vertex line 5 ('3 0 1 2') is not 3 numbers"),
    ("blank lines between", ply_ascii(5, faces=2, vertices=["\n", "1 2 3\n", " \t\r\n"] + BAD[1:] + ["\n"]),
     "vertex line 2 ('1 2 3 7') is not 3 numbers"),
    ("the last vertex cut short", ply_ascii(5, faces=0, vertices=GOOD[:4] + ["1 2"]), "truncated: its last line ('1 2')"),
])
def test_an_ascii_ply_read_once_says_what_it_said(tmp_path, name, data, message):
    """The count of lines is checked before the lines' numbers, as when they were two passes."""
    path = tmp_path / "edited.ply"
    path.write_bytes(data)
    if message is None:
        assert check_cloud_file(path) == path
        return
    with pytest.raises(InputError, match=re.escape(message)):
        check_cloud_file(path)


# ------------------------------------------------------------------------------------------------
# the lines of ASCII clouds, checked a block at a time
# ------------------------------------------------------------------------------------------------

def _row_pattern(fields: int) -> re.Pattern[bytes]:
    """A whole line of ``fields`` numbers (one if 0), as the check matched each line (the number written out
    ``fields`` times)."""
    from pcreg.cloud_files import _ASCII_NUMBER

    return re.compile(rb"\s*" + _ASCII_NUMBER + (rb"\s+" + _ASCII_NUMBER) * (fields - 1) + rb"\s*")


def _line_by_line(path, start, *, stop, rows, fields):
    """What _scan_rows must give: each line read and matched by the line's pattern in turn (the check as it was)."""
    row = None if fields is None else _row_pattern(fields)
    count, bad = 0, None
    with open(path, "rb") as fh:
        fh.seek(start)
        for line in fh:
            if not line.strip():
                continue
            if row is not None and bad is None and rows[0] <= count < rows[1] and row.fullmatch(line) is None:
                bad = (count - rows[0] + 1, line)
            count += 1
            if count >= stop:
                break
    return count, bad


PIECES = [b"1", b"-2.5", b".5", b"5.", b"1e5", b"1E-05", b"+.5e+3", b"5.e3", b"007", b"nan", b"-nan(ind)", b"NaN",
          b"inf", b"-Infinity", b"1,0", b"1_0", b"0x1p3", b"e5", b"1e", b"--1", b"+-1", b"1.2.3", b"1e5.3", b"1e5e3",
          b".", b"+", b"-.", b".e1", b"1e+-5", b"\x00", b"\xff", b"x", b" ", b" ", b"\t", b"\r", b"\x0b", b"\x0c",
          b"\n", b"\n", b"\n", b"\r\n"]


@settings(max_examples=400, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(body=st.lists(st.one_of(st.sampled_from(PIECES), st.binary(min_size=1, max_size=3)), max_size=80),
       fields=st.sampled_from([None, 0, 1, 3]), stop=st.integers(1, 12), first=st.integers(0, 4),
       block=st.sampled_from([4, 16, 1 << 20]))
def test_lines_checked_a_block_at_a_time_say_what_line_by_line_said(tmp_path, monkeypatch, body, fields, stop, first,
                                                                    block):
    """The same count and the same first bad line (its number and bytes) as the pattern line by line, whatever
    the bytes, blank lines, a last line without its newline, or lines longer than a block."""
    import pcreg.cloud_files as cloud_files

    monkeypatch.setattr(cloud_files, "_SCAN_BYTES", block)
    path = tmp_path / "lines.txt"
    path.write_bytes(b"HEAD\n" + b"".join(body))
    for rows in ((0, stop - 1), (first, first + 3)):
        assert cloud_files._scan_rows(path, 5, stop=stop, rows=rows, fields=fields) == \
            _line_by_line(path, 5, stop=stop, rows=rows, fields=fields)


@pytest.mark.slow
@pytest.mark.parametrize("numbers", [1, 2])
def test_plain_lines_are_exactly_the_patterns_own(numbers):
    """Every line of up to six of 0 . + - e and space, of up to five of - e N a I f and space (in blocks), and
    every text of up to four of 0 . + - e n f, space and newline (a last line without one): a line is found plain
    if and only if the pattern takes it (nan(...), which the pattern also takes, is left to it)."""
    import itertools

    from pcreg.cloud_files import _plain_rows

    row = _row_pattern(numbers)

    def agree(buf):
        ends, filled, plain = _plain_rows(buf, numbers)
        assert int(ends[-1]) == len(buf) - 1
        for s, e, f, p in zip(np.r_[0, ends[:-1] + 1], ends, filled, plain):
            line = buf[s:e + 1]
            taken = row.fullmatch(line) is not None
            assert f == bool(line.strip()) and (p == taken or (taken and b"(" in line)), line

    lines = [bytes(t) + b"\n" for n in range(7) for t in itertools.product(b"0.+-e ", repeat=n)]
    lines += [bytes(t) + b"\n" for n in range(6) for t in itertools.product(b"-eNaIf ", repeat=n)]
    lines += [b"%s %s\n" % (a, b) for a in (b"infinity", b"-INFinity", b"infinit", b"infinityy", b"nan(ind)", b"1")
              for b in (b"+nan", b"inf", b"1e5")]
    for i in range(0, len(lines), 20_000):
        agree(b"".join(lines[i:i + 20_000]))
    for n in range(1, 5):
        for text in itertools.product(b"0.+-enf \n", repeat=n):
            agree(bytes(text))


def test_the_pattern_reads_only_lines_that_are_not_plain_numbers(tmp_path, monkeypatch):
    """A million-point ASCII PCD took 3.4-4.8 s, one pattern match a line: lines of plain numbers (nan and inf
    too) are now checked as arrays, and only nan(...) and damage go to the pattern (which decides, as before)."""
    import pcreg.cloud_files as cloud_files

    matched = []
    pattern = cloud_files._row_pattern

    class Counting:
        def __init__(self, numbers):
            self.row = pattern(numbers)

        def fullmatch(self, buf, first, last):
            matched.append(buf[first:last])
            return self.row.fullmatch(buf, first, last)

    monkeypatch.setattr(cloud_files, "_row_pattern", Counting)
    pts = np.random.default_rng(2).normal(size=(1000, 3)).astype("<f4")
    rows = [f"{a} {b} {c}\n" for a, b, c in pts]
    rows[10], rows[500] = "nan 1.5 -inf\n", "1e-3 -nan(ind) 2\n"
    path = tmp_path / "ascii.pcd"
    path.write_bytes(pcd_head(1000, "ascii") + "".join(rows).encode())
    assert check_cloud_file(path) == path
    assert matched == [b"1e-3 -nan(ind) 2\n"]
    path.write_bytes(pcd_head(1000, "ascii") + "".join(rows[:700] + ["1 2 3,5\n"] + rows[701:]).encode())
    with pytest.raises(InputError, match=re.escape("data line 701 ('1 2 3,5') is not 3 numbers, as the header")):
        check_cloud_file(path)


def test_a_count_of_a_billion_is_checked_line_by_line_in_bounded_memory(tmp_path):
    """COUNT 1 1 100000 in a 10 kB ASCII PCD took 64 s and 1.2 GB (a pattern repeating the number 100,002 times),
    a million more than 300 s, and a billion ran out of memory naming no file: the pattern counts its repeats."""
    pts = np.random.default_rng(2).normal(size=(300, 3)).astype("<f4")
    body = "".join(f"{a} {b} {c}\n" for a, b, c in pts).encode()
    for count in (100_000, 1_000_000_000):
        path = tmp_path / f"count_{count}.pcd"
        path.write_bytes(pcd_head(300, "ascii", count=f"1 1 {count}") + body)
        with pytest.raises(InputError, match=re.escape(f"count_{count}.pcd: data line 1 (")) as err:
            check_cloud_file(path)
        assert f"is not {count + 2} numbers, as the header declares" in str(err.value)


# ------------------------------------------------------------------------------------------------
# hostile PCD and PLY files on the command line: one line, exit 2
# ------------------------------------------------------------------------------------------------

def _points_text() -> bytes:
    pts = np.random.default_rng(2).normal(size=(300, 3)).astype("<f4")
    return "".join(f"{a} {b} {c}\n" for a, b, c in pts).encode()


PLY_HEAD = b"ply\nformat ascii 1.0\nelement vertex 300\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
HOSTILE = {
    "header_only_ascii.pcd": (lambda: pcd_head(300, "ascii"), "truncated PCD: the header declares 300 points, the file holds 0"),
    "header_only_binary.pcd": (lambda: pcd_head(300, "binary"), "the file holds 0 bytes"),
    "header_only_compressed.pcd": (lambda: pcd_head(300, "binary_compressed"), "truncated PCD (no compressed block)"),
    "header_only.ply": (lambda: PLY_HEAD, "truncated PLY: the header declares 300 vertices, the file holds 0"),
    "points_negative.pcd": (lambda: pcd_head(300, "ascii").replace(b"POINTS 300", b"POINTS -300") + _points_text(),
                            "no points in the PCD header"),
    "points_not_an_integer.pcd": (lambda: pcd_head(300, "ascii").replace(b"POINTS 300", b"POINTS 300.0") + _points_text(),
                                  "damaged PCD header (POINTS, SIZE, COUNT)"),
    "count_short.pcd": (lambda: pcd_head(300, "ascii", count="1 1") + _points_text(), "SIZE and COUNT disagree"),
    "count_a_billion.pcd": (lambda: pcd_head(300, "ascii", count="1 1 1000000000") + _points_text(),
                            "is not 1000000002 numbers"),
    "inf_coordinate.pcd": (lambda: pcd_head(300, "ascii") + b"inf 1 2\n" + _points_text().split(b"\n", 1)[1],
                           "1 point(s) have NaN or inf coordinates"),
    "cut_inside_its_last_line.pcd": (lambda: pcd_head(300, "ascii") + _points_text()[:_points_text().rindex(b" ") - 2],
                                     "is cut short"),
    "compressed_junk.pcd": (lambda: compressed(pcd_head(300, "binary_compressed"), 3600, bytes(range(100))),
                            "Uncompression failed"),
}


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_hostile_clouds_are_one_line_and_exit_2(tmp_path, capsys, name):
    from pcreg.cli import main

    make, message = HOSTILE[name]
    (tmp_path / name).write_bytes(make())
    (tmp_path / "ok.ply").write_bytes(PLY_HEAD + _points_text())
    rc = main(["crosscheck", str(tmp_path / name), str(tmp_path / "ok.ply")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "Traceback" not in err[0], err
    assert f"{name}: " in err[0] and message in err[0], err


def test_crlf_clouds_read_as_their_lf_twins(tmp_path):
    from pcreg.implementations.crosscheck import load_cloud

    for name, text in (("c.pcd", pcd_head(300, "ascii") + _points_text()), ("c.ply", PLY_HEAD + _points_text())):
        (tmp_path / f"lf_{name}").write_bytes(text)
        (tmp_path / f"crlf_{name}").write_bytes(text.replace(b"\n", b"\r\n"))
        np.testing.assert_array_equal(load_cloud(tmp_path / f"crlf_{name}"), load_cloud(tmp_path / f"lf_{name}"))
