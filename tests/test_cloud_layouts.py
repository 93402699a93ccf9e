"""PCD and PLY files in the layouts PCL, Open3D, plyfile and trimesh write and test with: PCL's point types (packed
rgb floats, rgba with padding fields, a descriptor of many numbers, integer coordinates, organised clouds with
VIEWPOINT and comments), and the header spellings Open3D's readers take otherwise than PCL and plyfile. Each file
is read as Open3D reads it where Open3D reads it right, and refused in one line where it does not."""

from __future__ import annotations

import re

import numpy as np
import open3d as o3d
import pytest

from pcreg.cli import main
from pcreg.cloud_reader import load_cloud
from pcreg.errors import InputError

POINTS = np.random.default_rng(5).uniform(-3, 3, (50, 3)).astype(np.float32)


def pcd(kind: str, *, fields: str = "x y z", size: str = "4 4 4", type_: str = "F F F", count: str = "1 1 1",
        width: int = 50, height: int = 1, extra: str = "") -> bytes:
    return (f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {fields}\nSIZE {size}\nTYPE {type_}\n"
            f"COUNT {count}\n{extra}WIDTH {width}\nHEIGHT {height}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {width * height}\n"
            f"DATA {kind}\n").encode()


def lines(rows) -> bytes:
    return "".join(" ".join(f"{v:.9g}" for v in row) + "\n" for row in rows).encode()


def _xyzrgb():
    rgb = np.random.default_rng(1).integers(0, 1 << 24, 50).astype(np.uint32).view(np.float32)
    return pcd("ascii", fields="x y z rgb", size="4 4 4 4", type_="F F F F", count="1 1 1 1") + \
        lines(np.c_[POINTS, rgb])


def _fpfh():
    hist = np.random.default_rng(2).uniform(0, 100, (50, 33))
    return pcd("ascii", fields="normal_x normal_y normal_z fpfh z y x", size="4 4 4 4 4 4 4",
               type_="F F F F F F F", count="1 1 1 33 1 1 1") + lines(np.c_[np.zeros((50, 3)), hist, POINTS[:, ::-1]])


def _rgba_padded():
    d = np.zeros(50, [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("_", "u1", (4,)), ("rgba", "<u4"), ("__", "u1", (12,))])
    d["x"], d["y"], d["z"] = POINTS.T
    d["rgba"] = 0xFF102030
    return pcd("binary", fields="x y z _ rgba _", size="4 4 4 1 4 1", type_="F F F U U U",
               count="1 1 1 4 1 12") + d.tobytes()


def _int16():
    q = np.round(POINTS * 1000).astype(np.int16)
    return pcd("ascii", fields="x y z intensity", size="2 2 2 1", type_="I I I U", count="1 1 1 1") + \
        lines(np.c_[q, np.full(50, 7)])


def _organised():
    grid = POINTS.copy()
    grid[::7] = np.nan
    head = pcd("ascii", width=10, height=5).replace(b"VIEWPOINT 0 0 0 1 0 0 0", b"VIEWPOINT 1 2 3 0.7071 0 0.7071 0")
    return (head.replace(b"SIZE", b"# a comment inside the header\nSIZE") + lines(grid)).replace(b"\n", b"\r\n")


def _spaced():
    body = "".join(f"  {a:+.6e}\t{b:.6E}  {c:g}  \n" for a, b, c in POINTS).encode()
    return pcd("ascii").replace(b"FIELDS x y z", b"FIELDS\tx  y\tz ") + body


def _v05_columns():
    head = pcd("ascii").replace(b"FIELDS", b"COLUMNS").replace(b"VERSION 0.7", b"VERSION .5")
    return head.replace(b"VIEWPOINT 0 0 0 1 0 0 0\n", b"") + lines(POINTS)


LAYOUTS = {"v05_columns": _v05_columns, "xyzrgb": _xyzrgb, "fpfh_before_zyx": _fpfh, "rgba_padded": _rgba_padded, "int16": _int16,
           "organised_viewpoint_crlf": _organised, "spaced_exponents": _spaced}


@pytest.mark.parametrize("name", sorted(LAYOUTS))
def test_pcl_point_types_read_as_open3d_reads_them(tmp_path, name):
    path = tmp_path / f"{name}.pcd"
    path.write_bytes(LAYOUTS[name]())
    theirs = np.asarray(o3d.io.read_point_cloud(str(path), remove_nan_points=True).points)
    np.testing.assert_array_equal(load_cloud(path), theirs)


def test_an_ascii_pcd_of_lines_longer_than_open3d_reads_is_read_whole(tmp_path):
    """A point with a histogram of 125 numbers (PCL's PFHSignature125) takes about 1,300 bytes a line; Open3D's
    reader takes 1,023 at a time, read none of these points and returned 50 of what its memory held."""
    hist = np.random.default_rng(3).uniform(0, 1, (50, 125))
    path = tmp_path / "pfh.pcd"
    path.write_bytes(pcd("ascii", fields="x y z pfh", size="4 4 4 4", type_="F F F F", count="1 1 1 125")
                     + lines(np.c_[POINTS, hist]))
    np.testing.assert_array_equal(load_cloud(path).astype(np.float32), POINTS)  # 9 digits: each float32 again


def test_integer_fields_of_an_ascii_pcd_are_read_in_decimal_and_whole(tmp_path):
    """Open3D read TYPE I numbers with C's strtol of base 0 (010 as 8) and cut 1.5 to 1; PCL reads 010 as 10."""
    path = tmp_path / "ints.pcd"
    path.write_bytes(pcd("ascii", type_="I I I", width=3) + b"010 -020 30\n1 2 3\n4 5 6\n")
    np.testing.assert_array_equal(load_cloud(path), [[10, -20, 30], [1, 2, 3], [4, 5, 6]])
    path.write_bytes(pcd("ascii", type_="I I I", width=3) + b"1 2 3\n4 5.5 6\n7 8 9\n")
    with pytest.raises(InputError, match="ints.pcd: its field y holds whole numbers \\(TYPE I\\), point 2 has y = 5.5"):
        load_cloud(path)


def _ply_uint16(end: bytes, newline: bytes = b"\n") -> bytes:
    """A binary PLY of whole-number coordinates (which a read from the wrong byte turns into other numbers in
    range), its header lines ending in ``newline`` but the last, ``end``."""
    q = np.round(POINTS * 1000 + 4000).astype("<u2")
    head = [b"ply", b"format binary_little_endian 1.0", b"element vertex 50", b"property ushort x",
            b"property ushort y", b"property ushort z"]
    return b"".join(line + newline for line in head) + end + q.tobytes()


def test_binary_plys_whose_header_lines_end_alike_read_as_written(tmp_path):
    want = np.round(POINTS * 1000 + 4000).astype(np.float64)
    for name, data in (("lf.ply", _ply_uint16(b"end_header\n")), ("crlf.ply", _ply_uint16(b"end_header\r\n", b"\r\n"))):
        (tmp_path / name).write_bytes(data)
        np.testing.assert_array_equal(load_cloud(tmp_path / name), want)


def _count_before_size() -> bytes:
    head = pcd("binary", fields="n x y z", size="4 4 4 4", type_="F F F F", count="2 1 1 1")
    head = head.replace(b"SIZE 4 4 4 4\nTYPE F F F F\nCOUNT 2 1 1 1\n", b"COUNT 2 1 1 1\nSIZE 4 4 4 4\nTYPE F F F F\n")
    return head + np.c_[np.full((50, 2), 7, np.float32), POINTS].astype("<f4").tobytes()


HOSTILE = {
    # Open3D's PLY reader (RPly) starts the data one byte after end_header (two after a first line 'ply\r\n')
    "end_header_blank.ply": (lambda: _ply_uint16(b"end_header \n"), "its end_header line ends in ' \\n'"),
    "end_header_crlf.ply": (lambda: _ply_uint16(b"end_header\r\n"), "its end_header line ends in '\\r\\n', its first"),
    "end_header_lf_after_crlf.ply": (lambda: _ply_uint16(b"end_header\n", b"\r\n"),
                                     "its end_header line ends in '\\n', its first line in '\\r\\n'"),
    # PCL and Open3D match the keywords in upper case and the DATA kinds in lower case
    "lower_case_data.pcd": (lambda: pcd("ascii").replace(b"DATA", b"data") + lines(POINTS),
                            "its keyword must be upper case, DATA"),
    "upper_case_binary.pcd": (lambda: pcd("BINARY") + POINTS.tobytes(), "unknown PCD DATA kind 'BINARY'"),
    # Open3D places the fields of a binary PCD by the SIZE line alone when COUNT comes before it
    "fields_more_than_sizes.pcd": (lambda: pcd("ascii", fields="w x y z") + lines(POINTS),
                                   "damaged PCD header (FIELDS names 4 fields, SIZE gives 3)"),
    "count_before_size.pcd": (_count_before_size, "its COUNT line comes before SIZE"),
    # PCL refuses WIDTH x HEIGHT other than POINTS; Open3D read the count of the later line (here 25 of 50 points)
    "points_before_width.pcd": (lambda: pcd("binary").replace(b"POINTS 50\n", b"").replace(b"WIDTH 50", b"POINTS 50\nWIDTH 25")
                                + POINTS.tobytes(), "WIDTH 25 x HEIGHT 1 is not its POINTS 50"),
}


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_header_spellings_open3d_misreads_are_one_line_and_exit_2(tmp_path, capsys, name):
    make, message = HOSTILE[name]
    (tmp_path / name).write_bytes(make())
    np.save(tmp_path / "ok.npy", POINTS.astype(np.float64))
    rc = main(["crosscheck", str(tmp_path / name), str(tmp_path / "ok.npy")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "Traceback" not in err[0], err
    assert f"{name}: " in err[0] and message in err[0], err


@pytest.mark.parametrize("line, shown", [("100 200 3,5", "100 200 3,5"), ("1 2 3abc", "1 2 3abc"),
                                         ("0x10 1 2", "0x10 1 2"), ("1 2 3 4", "1 2 3 4")])
def test_a_text_cloud_line_open3d_reads_in_part_is_refused_naming_it(tmp_path, line, shown):
    """Open3D reads an .xyz line with sscanf: ``100 200 3,5`` (a decimal comma) came back as (100, 200, 3),
    ``3abc`` as 3 and ``0x10`` as 16, without a word; every line is now as many plain numbers as the first."""
    path = tmp_path / "scan.xyz"
    path.write_text("".join(f"{a} {b} {c}\n" for a, b, c in POINTS[:10]) + line + "\n")
    with pytest.raises(InputError, match=f"scan.xyz: point line 11 \\('{re.escape(shown)}'\\) is not 3 numbers"):
        load_cloud(path)
    path.write_text("".join(f"{a} {b} {c} 10 20 30\n" for a, b, c in POINTS))  # colour columns after x y z
    np.testing.assert_array_equal(load_cloud(path), POINTS.astype(np.float64))


def test_a_pts_cloud_without_its_count_line_is_refused_saying_so(tmp_path):
    """Open3D read the first point's x as the count of a .pts file without one: one point, said as '19 of 20
    lines are not points'."""
    rows = "".join(f"{a} {b} {c} 10 20 30\n" for a, b, c in POINTS)
    (tmp_path / "counted.pts").write_text(f"{len(POINTS)}\n" + rows)
    np.testing.assert_array_equal(load_cloud(tmp_path / "counted.pts"), POINTS.astype(np.float64))
    (tmp_path / "bare.pts").write_text(rows)
    with pytest.raises(InputError, match="bare.pts: its first line \\('1.83.*'\\) is not the point count a .pts file"):
        load_cloud(tmp_path / "bare.pts")


@pytest.mark.parametrize("columns", ["{a} {b} {c} -1204 83 91 77", "{a} {b} {c} 0.4521",
                                     "{a} {b} {c} 0.325 0.31 0.298", "{a}\t{b}\t{c}\t-87\t12\t200\t255\r",
                                     "{a} {b} {c}"])
def test_a_pts_cloud_as_cyclone_and_cloudcompare_write_it_is_read(tmp_path, columns):
    """Leica Cyclone's and CloudCompare's .pts: the count, then x y z intensity r g b (or x y z intensity, or x y z
    and colours as fractions); x y z are each line's first three numbers. Open3D refused the intensity ('only
    points and colors attributes are supported') and fractional colours ('Read PTS failed at line')."""
    path = tmp_path / "scan.pts"
    path.write_text(f"{len(POINTS)}\n" + "".join(columns.format(a=a, b=b, c=c) + "\n" for a, b, c in POINTS))
    np.testing.assert_array_equal(load_cloud(path), POINTS.astype(np.float64))


def test_a_damaged_pts_line_is_still_refused(tmp_path):
    rows = [f"{a} {b} {c} -1204 83 91 77" for a, b, c in POINTS]
    rows[7] = rows[7].rsplit(" ", 1)[0]
    (tmp_path / "short.pts").write_text(f"{len(rows)}\n" + "\n".join(rows) + "\n")
    with pytest.raises(InputError, match="short.pts: point line 8 .* is not 7 numbers, as the first is"):
        load_cloud(tmp_path / "short.pts")
    (tmp_path / "flat.pts").write_text("2\n1 2\n3 4\n")
    with pytest.raises(InputError, match="flat.pts: its point lines hold 2 numbers \\(x, y and z are needed\\)"):
        load_cloud(tmp_path / "flat.pts")
    (tmp_path / "none.pts").write_text("0\n")
    with pytest.raises(InputError, match="none.pts: no points could be read"):
        load_cloud(tmp_path / "none.pts")


def test_a_pts_count_is_checked_before_open3d_reserves_it(tmp_path, monkeypatch):
    """Open3D reserved the points a .pts file's first line declares before reading them: a count of 20 million
    in a file of three lines took 800 MB, and came back as 20 million points, all but two at the origin."""
    (tmp_path / "lying.pts").write_text("20000000\n1 2 3\n4 5 6\n")

    def read(*args, **kwargs):
        raise AssertionError("the count reached Open3D's reader")

    monkeypatch.setattr(o3d.io, "read_point_cloud", read)
    with pytest.raises(InputError, match="lying.pts: the first line declares 20000000 points, the file holds 2 lines"):
        load_cloud(tmp_path / "lying.pts")
    (tmp_path / "comma.xyz").write_text("1,2,3\n4,5,6\n")
    with pytest.raises(InputError, match="comma.xyz: its first point line \\('1,2,3'\\) is not numbers between"):
        load_cloud(tmp_path / "comma.xyz")


@pytest.mark.parametrize("suffix", [".xyz", ".xyzn", ".xyzrgb"])
def test_a_text_cloud_whose_lines_end_in_a_lone_cr_is_refused(tmp_path, suffix):
    """A file whose lines end in a carriage return alone (as classic Mac OS and some exporters write them) is one
    line to Open3D's reader, which read its first point and dropped every other without a word."""
    rows = np.c_[POINTS, np.zeros((len(POINTS), 3))] if suffix != ".xyz" else POINTS
    path = tmp_path / f"mac{suffix}"
    path.write_bytes(lines(rows).replace(b"\n", b"\r"))
    with pytest.raises(InputError, match=f"mac{re.escape(suffix)}: its lines end in a carriage return alone"):
        load_cloud(path)
    path.write_bytes(lines(rows).replace(b"\n", b"\r\n"))  # Windows' line ends are read
    np.testing.assert_array_equal(load_cloud(path).astype(np.float32), POINTS)


@pytest.mark.parametrize("suffix, numbers, need", [(".xyz", 2, "x, y and z"), (".xyzn", 3, "x, y, z and a normal"),
                                                   (".xyzrgb", 4, "x, y, z and a colour")])
def test_a_text_cloud_of_too_few_numbers_a_line_says_so(tmp_path, suffix, numbers, need):
    """Open3D's reader reads no point of such a file; it was said to be 'empty or not a .xyz point cloud'."""
    path = tmp_path / f"short{suffix}"
    path.write_bytes(lines(np.c_[POINTS, POINTS][:, :numbers]))
    with pytest.raises(InputError, match=f"short{re.escape(suffix)}: its point lines hold {numbers} numbers \\({need}"):
        load_cloud(path)


@pytest.mark.parametrize("suffix, head", [(".xyz", b""), (".pts", b"50\n")])
def test_a_text_cloud_that_starts_with_a_byte_order_mark_says_so(tmp_path, suffix, head):
    """A UTF-8 byte-order mark was shown as three replacement characters before the first line's numbers."""
    path = tmp_path / f"marked{suffix}"
    path.write_bytes(b"\xef\xbb\xbf" + head + lines(POINTS))
    with pytest.raises(InputError, match=f"marked{re.escape(suffix)}: it starts with a UTF-8 byte-order mark"):
        load_cloud(path)
