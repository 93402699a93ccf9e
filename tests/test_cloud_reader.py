"""Point-cloud files in the layouts other ICP projects ship their test data in: columns of numbers in .txt and
.csv (pycpd, probreg, libpointmatcher, libnabo, CloudCompare's export), PCL's organised PCDs whose pixels
without a measurement are NaN. Each file here is built in the layout of the project's own file."""

import struct

import numpy as np
import pytest

from pcreg.cloud_reader import load_cloud, read_columns
from pcreg.errors import InputError


@pytest.fixture
def pts():
    return np.random.default_rng(0).normal(size=(40, 3))


def test_text_columns_as_numpy_pycpd_and_libnabo_write_them(tmp_path, pts):
    np.savetxt(tmp_path / "bunny.txt", pts)  # pycpd data/bunny_*.txt: "%.18e" and one space
    np.testing.assert_array_equal(load_cloud(tmp_path / "bunny.txt"), pts)
    np.savetxt(tmp_path / "fish.txt", pts[:, :2])  # pycpd data/fish_*.txt: a 2-D cloud
    assert load_cloud(tmp_path / "fish.txt").shape == (40, 2)
    # libpointmatcher 2D_twoBoxes.csv, libnabo scan.2d.txt: columns padded with spaces
    (tmp_path / "boxes.csv").write_text("".join(f"   {x:.7e}   {y:.7e}\n" for x, y in pts[:, :2]))
    np.testing.assert_allclose(load_cloud(tmp_path / "boxes.csv"), pts[:, :2], rtol=1e-7)
    (tmp_path / "tabs.txt").write_text("# exported\n\n" + "".join(f"{x}\t{y}\t{z}\r\n" for x, y, z in pts))
    np.testing.assert_array_equal(load_cloud(tmp_path / "tabs.txt"), pts)


def test_a_first_line_of_names_says_which_columns_are_x_y_z(tmp_path, pts):
    normals = np.random.default_rng(1).normal(size=(40, 3))
    # libpointmatcher car_cloud400.csv: "x,y,z,nx,ny,nz", then "a , b , c , d,e,f"
    rows = "".join(f"{a} , {b} , {c} , {d},{e},{f}\n" for (a, b, c), (d, e, f) in zip(pts, normals))
    (tmp_path / "car.csv").write_text("x,y,z,nx,ny,nz\n" + rows)
    np.testing.assert_array_equal(load_cloud(tmp_path / "car.csv"), pts)
    # CloudCompare's ASCII export: "//X,Y,Z,R,G,B", colour first here
    rows = "".join(f"255;0;7;{a};{b};{c}\n" for a, b, c in pts)
    (tmp_path / "cc.txt").write_text("//R;G;B;X;Y;Z\n" + rows)
    np.testing.assert_array_equal(load_cloud(tmp_path / "cc.txt"), pts)
    (tmp_path / "xy.csv").write_text("id,x,y\n" + "".join(f"{i},{a},{b}\n" for i, (a, b, _) in enumerate(pts)))
    np.testing.assert_array_equal(load_cloud(tmp_path / "xy.csv"), pts[:, :2])


def test_named_x_y_z_columns_are_read_beside_a_column_of_text(tmp_path, pts):
    """A labelled export (``x,y,z,label``, text labels): the named columns are read and the others left out; it
    was refused ('line 2 ... is not 4 numbers, as the first'). A line of other fields, or text where x, y or z
    is, stays refused, naming it; without a first line of names, text is refused as before."""
    labels = ["car", "tree", "road"]
    rows = "".join(f"{a},{b},{c},{labels[i % 3]}\n" for i, (a, b, c) in enumerate(pts))
    (tmp_path / "labelled.csv").write_text("x,y,z,label\n" + rows)
    np.testing.assert_array_equal(load_cloud(tmp_path / "labelled.csv"), pts)
    rows = "".join(f"{labels[i % 3]}\t{i}\t{c}\t{b}\t{a}\n" for i, (a, b, c) in enumerate(pts))
    (tmp_path / "spaced.txt").write_text("class id Z Y X\n" + rows)
    np.testing.assert_array_equal(load_cloud(tmp_path / "spaced.txt"), pts)
    (tmp_path / "last.csv").write_text("x,y,label\n1,2,car\n3,4,tree")  # no newline after the last line
    np.testing.assert_array_equal(load_cloud(tmp_path / "last.csv"), [[1, 2], [3, 4]])
    (tmp_path / "oops.csv").write_text("x,y,z,label\n1,2,3,car\n4,oops,6,tree\n")
    with pytest.raises(InputError, match="oops.csv: line 3 \\('4,oops,6,tree'\\): its y, 'oops', is not a number"):
        load_cloud(tmp_path / "oops.csv")
    (tmp_path / "short.csv").write_text("x,y,z,label\n1,2,3,car\n4,5,6\n")
    with pytest.raises(InputError, match="short.csv: line 3 \\('4,5,6'\\) has 3 fields, the first line names 4"):
        load_cloud(tmp_path / "short.csv")
    (tmp_path / "long.csv").write_text("x,y,z,label\n1,2,3,car\n4,5,6,tree,7\n")
    with pytest.raises(InputError, match="long.csv: line 3 .* has 5 fields, the first line names 4"):
        load_cloud(tmp_path / "long.csv")
    (tmp_path / "cut.csv").write_text("x,y,z,label\n1,2,3,car\n4,5")
    with pytest.raises(InputError, match="cut.csv: line 3 \\('4,5'\\) is cut short"):
        load_cloud(tmp_path / "cut.csv")
    (tmp_path / "bare.csv").write_text("1,2,car\n3,4,tree\n")
    with pytest.raises(InputError, match="bare.csv: its first line \\('1,2,car'\\) names no x and y columns"):
        load_cloud(tmp_path / "bare.csv")


def test_paraview_and_vtk_point_columns_are_x_y_z(tmp_path):
    """ParaView's CSV export names the coordinates "Points:0","Points:1","Points:2" (and VTK-derived writers
    Points_0, ...): read as x, y and z, the other columns left out; they were refused as naming no x and y. A first
    line that names x or y keeps them: Points:0 is then a column like any other."""
    (tmp_path / "paraview.csv").write_text('"vtkOriginalIndices","Points:0","Points:1","Points:2"\n0,1.5,2,3\n1,4,5,6\n')
    np.testing.assert_array_equal(load_cloud(tmp_path / "paraview.csv"), [[1.5, 2, 3], [4, 5, 6]])
    (tmp_path / "vtk.csv").write_text("Points_0,Points_1,Points_2,Point ID\n1,2,3,0\n4,5,6,1\n")
    np.testing.assert_array_equal(load_cloud(tmp_path / "vtk.csv"), [[1, 2, 3], [4, 5, 6]])
    (tmp_path / "both.csv").write_text("Points_0,x,y\n9,1,2\n9,3,4\n")
    np.testing.assert_array_equal(load_cloud(tmp_path / "both.csv"), [[1, 2], [3, 4]])


def test_a_csv_that_starts_with_a_byte_order_mark_is_read(tmp_path, pts):
    """A spreadsheet's "CSV UTF-8" export (Excel's) starts with the bytes EF BB BF: its first line was taken for
    names that name no x and y ('\ufffd\ufffd\ufffdx,y,z'), a first line of numbers too."""
    rows = "".join(f"{a},{b},{c}\r\n" for a, b, c in pts)
    for name, text in (("names.csv", "X,Y,Z\r\n" + rows), ("numbers.csv", rows)):
        (tmp_path / name).write_bytes(b"\xef\xbb\xbf" + text.encode())
        np.testing.assert_array_equal(load_cloud(tmp_path / name), pts)
    (tmp_path / "bad.csv").write_bytes(b"\xef\xbb\xbf1,2,3\n4,5\n")
    with pytest.raises(InputError, match="bad.csv: line 2 \\('4,5'\\) is not 3 numbers"):
        load_cloud(tmp_path / "bad.csv")


def test_quoted_fields_as_csv_writers_quote_them_are_read(tmp_path, pts):
    """Python's csv module and pandas with ``quoting=QUOTE_ALL`` (``"1.0","2.0","3.0"``), or a header quoted alone
    (``QUOTE_NONNUMERIC``), or a text column quoted because it holds the separator (``"car, red"``): refused as
    'is not a number', or as naming no x and y columns."""
    import csv

    def written(name, rows, header=None, **options):
        with open(tmp_path / name, "w", newline="") as fh:
            out = csv.writer(fh, **options)
            if header:
                out.writerow(header)
            out.writerows(rows)
        return tmp_path / name

    every = written("all.csv", pts.tolist(), ("x", "y", "z"), quoting=csv.QUOTE_ALL)
    assert every.read_bytes().startswith(b'"x","y","z"\r\n"')  # Excel's dialect: CRLF
    np.testing.assert_array_equal(load_cloud(every), pts)
    np.testing.assert_array_equal(load_cloud(written("bare.csv", pts.tolist(), quoting=csv.QUOTE_ALL)), pts)
    np.testing.assert_array_equal(load_cloud(written("names.csv", pts.tolist(), ("x", "y", "z"),
                                                     quoting=csv.QUOTE_NONNUMERIC)), pts)
    labels = ["car, red", 'the "big" tree', "road # 3"]
    rows = [[*p, labels[i % 3]] for i, p in enumerate(pts.tolist())]
    np.testing.assert_array_equal(load_cloud(written("labels.csv", rows, ("x", "y", "z", "label"))), pts)
    (tmp_path / "oops.csv").write_text('"x","y","z"\n"1.0","2.0","3.0"\n"4.0","oops","6.0"\n')
    with pytest.raises(InputError, match="oops.csv: line 3 .*: its y, 'oops', is not a number"):
        load_cloud(tmp_path / "oops.csv")
    (tmp_path / "open.csv").write_text('"1.0","2.0","3.0"\n"4.0","5.0","6.0\n"7.0","8.0","9.0"\n')
    with pytest.raises(InputError, match="open.csv: line 2 .* has a quote that does not close on that line"):
        load_cloud(tmp_path / "open.csv")


def test_decimal_commas_between_semicolons_or_tabs_are_read(tmp_path, pts):
    """A spreadsheet in a German or French locale saves CSV as ``1,5;2,25;-3`` (Excel: with a byte-order mark and
    CRLF; quoted where asked) and text as tab-separated ``1,5\t2,25``; all were refused. A number that is not one
    in either mark (``1.234,5``, a thousands separator) is refused naming its line."""
    def comma(v):
        return repr(float(v)).replace(".", ",")

    rows = "".join(";".join(comma(v) for v in p) + "\r\n" for p in pts)
    (tmp_path / "excel.csv").write_bytes(b"\xef\xbb\xbf" + ("X;Y;Z\r\n" + rows).encode())
    np.testing.assert_array_equal(load_cloud(tmp_path / "excel.csv"), pts)
    (tmp_path / "bare.csv").write_text(rows)
    np.testing.assert_array_equal(load_cloud(tmp_path / "bare.csv"), pts)
    quoted = "".join(";".join(f'"{comma(v)}"' for v in p) + "\n" for p in pts)
    (tmp_path / "quoted.csv").write_text('"x";"y";"z"\n' + quoted)
    np.testing.assert_array_equal(load_cloud(tmp_path / "quoted.csv"), pts)
    tabs = "".join("\t".join(comma(v) for v in p) + "\n" for p in pts)
    for name, text in (("tabs.txt", tabs), ("named_tabs.txt", "x\ty\tz\n" + tabs)):
        (tmp_path / name).write_text(text)
        np.testing.assert_array_equal(load_cloud(tmp_path / name), pts)
    (tmp_path / "text.txt").write_text("x y z label\n1.5 2 3 a,b\n")  # a comma in text between spaces: no decimal
    np.testing.assert_array_equal(load_cloud(tmp_path / "text.txt"), [[1.5, 2, 3]])
    (tmp_path / "points.csv").write_text("x;y;z\n1.5;2;3\n")  # a point between semicolons stays a point
    np.testing.assert_array_equal(load_cloud(tmp_path / "points.csv"), [[1.5, 2, 3]])
    (tmp_path / "thousands.csv").write_text("x;y;z\n1,5;2,0;3,0\n1.234,5;2,0;3,0\n")
    with pytest.raises(InputError, match="thousands.csv: line 3 .*: its x, '1.234,5', is not a number"):
        load_cloud(tmp_path / "thousands.csv")


@pytest.mark.parametrize("text", ["1,5 2,5 3,5\n4,5 5,5 6,5\n", "x y z\n1,5 2,5 3,5\n"])
def test_decimal_commas_between_spaces_are_refused_saying_so(tmp_path, text):
    """``1,5 2,5 3,5`` is ambiguous (a comma is also a separator) and refused; the refusal named a line of no x and
    y columns, or an x that is not a number, and not the decimal commas or how to save the file so it is read."""
    (tmp_path / "commas.txt").write_text(text)
    with pytest.raises(InputError, match="commas.txt: .*decimal commas are read between semicolons or tabs"):
        load_cloud(tmp_path / "commas.txt")


@pytest.mark.parametrize("text, match", [
    ("1 2 3\n4 5\n6 7 8\n", r"line 2 \('4 5'\) is not 3 numbers"),
    ("1 2 3\n4 5 6 7\n", r"line 2 \('4 5 6 7'\) is not 3 numbers"),
    ("1 2 3\n4 5_0 6\n", r"line 2 \('4 5_0 6'\) is not 3 numbers"),
    ("1 2 3\n4,5 6 7\n", r"line 2"),
    ("1 2 3\n4 5 6\n7 8", r"line 3 \('7 8'\) is cut short"),
    ("1 2 3 4\n5 6 7 8\n", r"4 numbers a line and no first line naming the x, y and z columns"),
    ("7\n8\n", r"1 number a line"),
    ("a,b,c\n1,2,3\n", r"its first line \('a,b,c'\) names no x and y columns"),
    ("x,x,z\n1,2,3\n", r"its first line names x twice \(columns 1 and 2\); keep one of them"),  # not "no x and y"
    ("x,y,z\n", r"no points could be read \(a first line of names and no line of numbers\)"),
    ("# nothing\n\n", r"no points could be read"),
    ("x,y,z\n1,2,3\n4,5\n", r"line 3 \('4,5'\) is not 3 numbers"),
])
def test_a_text_cloud_that_is_not_columns_of_numbers_is_refused_naming_the_line(tmp_path, text, match):
    path = tmp_path / "c.txt"
    path.write_text(text)
    with pytest.raises(InputError, match=f"{path.name}: {match}"):
        load_cloud(path)


def test_a_text_cloud_over_the_point_limit_is_refused(tmp_path, pts):
    np.savetxt(tmp_path / "c.csv", pts, delimiter=",")
    assert read_columns(tmp_path / "c.csv", limit=40).shape == (40, 3)
    with pytest.raises(InputError, match="more than 39 points exceed the limit"):
        read_columns(tmp_path / "c.csv", limit=39)


def _organised_pcd(path, grid, kind):
    """An organised PCD as PCL writes a depth camera's cloud: WIDTH x HEIGHT, NaN where nothing was measured."""
    h, w, _ = grid.shape
    head = (f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\n"
            f"COUNT 1 1 1 1\nWIDTH {w}\nHEIGHT {h}\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {w * h}\nDATA {kind}\n")
    flat = grid.reshape(-1, 3)
    if kind == "ascii":
        body = "".join(f"{x} {y} {z} 4.2108e+06\n" for x, y, z in flat).encode()
    else:
        body = b"".join(struct.pack("<4f", x, y, z, 1.0) for x, y, z in flat)
    path.write_bytes(head.encode() + body)


@pytest.mark.parametrize("kind", ["ascii", "binary"])
def test_an_organised_pcd_is_read_without_its_unmeasured_points(tmp_path, kind):
    grid = np.random.default_rng(2).uniform(0.5, 3.0, (6, 8, 3)).astype(np.float32)
    grid[0, :] = np.nan  # a row of the depth image with no return, and scattered holes
    grid[3, 2] = grid[5, 7] = np.nan
    path = tmp_path / "office.pcd"
    _organised_pcd(path, grid, kind)
    measured = grid.reshape(-1, 3)[~np.isnan(grid.reshape(-1, 3)).all(axis=1)]
    np.testing.assert_array_equal(load_cloud(path), measured.astype(np.float64))
    _organised_pcd(path, np.full((2, 3, 3), np.nan, np.float32), kind)
    with pytest.raises(InputError, match="every point's coordinates are NaN \\(no point was measured\\)"):
        load_cloud(path)


@pytest.mark.parametrize("kind", ["ascii", "binary"])
def test_a_pcd_point_with_some_coordinates_nan_is_left_out_as_pcl_leaves_it(tmp_path, kind):
    """PCL's removeNaNFromPointCloud leaves out a point whose x, y or z is NaN (pcl::isFinite of each); such a
    point was refused ('1 point(s) have NaN or inf coordinates'), the whole file with it."""
    grid = np.random.default_rng(3).uniform(0.5, 3.0, (4, 5, 3)).astype(np.float32)
    grid[1, 2] = np.nan
    grid[2, 3, 0] = grid[3, 0, 1] = grid[0, 4, 2] = np.nan  # "nan 1 2", "1 nan 2", "1 2 nan"
    grid[0, 0, :2] = np.nan
    path = tmp_path / "holes.pcd"
    _organised_pcd(path, grid, kind)
    flat = grid.reshape(-1, 3)
    kept = flat[~np.isnan(flat).any(axis=1)]
    assert len(kept) == 20 - 5
    np.testing.assert_array_equal(load_cloud(path), kept.astype(np.float64))
    grid = np.ones((1, 3, 3), np.float32)
    grid[0, :, 1] = np.nan  # every point with a NaN y
    _organised_pcd(path, grid, kind)
    with pytest.raises(InputError, match="holes.pcd: every point has a coordinate that is NaN \\(no point was measured in full"):
        load_cloud(path)
    grid[0, 0, 1] = np.inf  # inf is not NaN: a damaged point, as before
    _organised_pcd(path, grid, kind)
    with pytest.raises(InputError, match="1 point\\(s\\) have NaN or inf coordinates"):
        load_cloud(path)


def test_two_dimensional_text_clouds_are_cross_checked_from_the_command_line(tmp_path, capsys):
    """pycpd's 2-D rigid test: the fish turned by 30 degrees and moved by (0.5, 1.0), here by less, so that an
    ICP from the identity reaches it."""
    import json

    from pcreg.cli import main

    fish = np.random.default_rng(3).uniform(-1, 1, (91, 2))
    a = np.radians(3.0)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    np.savetxt(tmp_path / "fish_target.txt", fish @ R + [0.02, 0.01])
    np.savetxt(tmp_path / "fish_source.txt", fish)
    assert main(["crosscheck", str(tmp_path / "fish_target.txt"), str(tmp_path / "fish_source.txt"),
                 "--max-distance", "0.5", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    T = np.array(out["implementations"]["reference"]["matrix"])
    np.testing.assert_allclose(T[:2, :2], R.T, atol=1e-9)
    np.testing.assert_allclose(T[:2, 2], [0.02, 0.01], atol=1e-9)


def test_crosscheck_of_files_of_an_unknown_type_says_so(tmp_path, capsys):
    """libpointmatcher's cloud.00000.vtk and cloud.00001.vtk with --with: the command took them for images and
    said '--with applies to point clouds'."""
    from pcreg.cli import main

    for name in ("cloud.00000.vtk", "cloud.00001.vtk"):
        (tmp_path / name).write_text("# vtk DataFile Version 3.0\ndata\nASCII\nDATASET POLYDATA\nPOINTS 1 float\n1 2 3\n")
    assert main(["crosscheck", str(tmp_path / "cloud.00000.vtk"), str(tmp_path / "cloud.00001.vtk"), "--with", "all"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"pcreg: error: {tmp_path / 'cloud.00000.vtk'}: unknown file type '.vtk' (an image: .png")
    assert ".txt, .csv)" in err


def test_crosscheck_of_a_cloud_without_its_suffix_says_how_clouds_are_read(tmp_path, capsys):
    """A .npy cloud saved without its suffix (``np.save`` adds it, a copy or download may drop it) is read as an
    image, and was refused as "not an image pcreg reads" alone: the refusal says that a cloud is read by its suffix."""
    from pcreg.cli import main

    np.save(tmp_path / "target.npy", np.random.default_rng(0).random((50, 3)))
    (tmp_path / "target.npy").rename(tmp_path / "target")
    np.save(tmp_path / "source.npy", np.random.default_rng(1).random((50, 3)))
    assert main(["crosscheck", str(tmp_path / "target"), str(tmp_path / "source.npy")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"pcreg: error: {tmp_path / 'target'}: not an image pcreg reads")
    assert "(a file without a suffix is read as an image; a point cloud is read by its suffix: .ply, .pcd" in err
    assert main(["crosscheck", str(tmp_path / "target"), str(tmp_path / "target")]) == 2  # two such: read as images
    assert "(a file without a suffix is read as an image; a point cloud is read by its suffix" in capsys.readouterr().err


@pytest.mark.parametrize("names", ["x,x,y,z", "X,Y,Z,x,y,z", "x,y,z,Points:0,z"])
def test_a_first_line_that_names_a_coordinate_twice_is_refused(tmp_path, names):
    """The first column of the name was taken, without a word: another file's join, or a ParaView export with
    its own x, may hold the coordinates in the second."""
    width = len(names.split(","))
    path = tmp_path / "twice.csv"
    path.write_text(names + "\n" + "\n".join(",".join(str(k + r) for k in range(width)) for r in range(4)) + "\n")
    with pytest.raises(InputError, match="twice.csv: its first line names [xyz] twice \\(columns [0-9]+ and [0-9]+\\)"):
        load_cloud(path)


@pytest.mark.parametrize("separator", [",", ";", " "])
def test_lines_of_numbers_ending_in_a_separator_are_read_with_names_and_refused_without(tmp_path, separator):
    """``1,2,3,`` a line (a spreadsheet's trailing separator) without a first line of names was refused as naming
    "no x and y columns", though it names none; it says what the file holds and the two ways out. With names
    (``x,y,z,``) the lines are read."""
    rows = [[1, 2, 3], [4, 5, 6], [7, 8, 9]]
    bare = tmp_path / "bare.csv"
    bare.write_text("".join(separator.join(map(str, r)) + separator + "\n" for r in rows))
    if separator != " ":  # a space at the end of a line is white space, not a field
        with pytest.raises(InputError, match=r"bare\.csv: its first line is 3 numbers and then an empty field .* add "
                                             r"a first line naming the columns, as 'x,y,z,'\)$"):
            load_cloud(bare)
    else:
        np.testing.assert_array_equal(load_cloud(bare), rows)
    named = tmp_path / "named.csv"
    named.write_text(separator.join("xyz") + separator + "\n" + bare.read_text())
    np.testing.assert_array_equal(load_cloud(named), rows)


@pytest.mark.parametrize("kind", ["ascii", "binary"])
@pytest.mark.parametrize("fields", ["rgba", "X Y Z"])
def test_a_pcd_without_x_y_z_is_refused_saying_so_whatever_its_data(tmp_path, kind, fields):
    """PCL's test files include PCDs of an image's colours (FIELDS rgba) and of descriptors: an ASCII one was
    refused saying its fields lack x, y or z, a binary one in Open3D's words ("[CheckHeader] Fields for point data
    are not complete"). Upper-case X Y Z, which PCL does not read as coordinates, says so too."""
    names = fields.split()
    n = 4
    head = (f"VERSION 0.7\nFIELDS {fields}\nSIZE {' '.join('4' for _ in names)}\nTYPE {' '.join('F' for _ in names)}\n"
            f"COUNT {' '.join('1' for _ in names)}\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\n"
            f"DATA {kind}\n")
    values = np.arange(n * len(names), dtype=np.float32).reshape(n, len(names))
    body = values.tobytes() if kind == "binary" else "".join(" ".join(map(str, row)) + "\n" for row in values).encode()
    path = tmp_path / "image.pcd"
    path.write_bytes(head.encode() + body)
    why = "PCL names the coordinates in lower case" if fields == "X Y Z" else "not a cloud of points"
    with pytest.raises(InputError, match=rf"image.pcd: PCD fields {fields} lack x, y or z: {why}"):
        load_cloud(path)


def _fixed_clouds(pts) -> dict[str, bytes]:
    """A cloud in each text layout, its numbers written in one fixed format (numpy's default ``%.18e``, six
    digits after the point as CloudCompare and most exports write them)."""
    rows6 = "".join(f"{x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in pts)
    n = len(pts)
    return {"numpy.txt": "".join(f"{x:.18e} {y:.18e} {z:.18e}\n" for x, y, z in pts).encode(),
            "export.csv": rows6.replace(" ", ",").encode(), "scan.xyz": rows6.encode(),
            "scan.pts": f"{n}\n{rows6}".encode(),
            "pcl.pcd": (f"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\n"
                        f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA ascii\n{rows6}").encode(),
            "mesh.ply": (f"ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\n"
                         f"property float z\nend_header\n{rows6}").encode()}


@pytest.mark.parametrize("name", ["numpy.txt", "export.csv", "scan.xyz", "scan.pts", "pcl.pcd", "mesh.ply"])
def test_a_text_cloud_cut_inside_its_last_number_is_refused(tmp_path, pts, name):
    """A copy cut short inside the last number (``0.4153`` of ``0.415384``) holds the right count of numbers:
    it was read with that number. Whole without its last line end, it is read."""
    data = _fixed_clouds(pts)[name]
    path = tmp_path / name
    for cut in (2, 4, 6):  # inside the last number (its digits, its point, its exponent)
        path.write_bytes(data[:-cut])
        with pytest.raises(InputError, match=rf"{name}: its last line ends inside a number: '[-0-9.e+]*' is shorter"):
            load_cloud(path)
    path.write_bytes(data[:-1])  # only the last line end missing
    np.testing.assert_allclose(load_cloud(path), pts, atol=1e-6)


def test_a_column_of_no_one_format_is_read_to_its_last_line(tmp_path, pts):
    """Numbers written in varying lengths (Python's ``repr``, ``%g``) say nothing of a cut: such a file without a
    last line end is read, as it was."""
    text = "\n".join(f"{x} {y} {z}" for x, y, z in np.round(pts, 3))  # no line end after the last
    (tmp_path / "joined.txt").write_text(text)
    np.testing.assert_array_equal(load_cloud(tmp_path / "joined.txt"), np.round(pts, 3))


def test_a_last_line_of_another_element_or_a_rounded_number_is_not_taken_for_a_cut(tmp_path, pts):
    """A PLY's one face after its vertices (``3 0 1 2``, no line end) was compared with the vertices' last column and
    refused as cut; a column whose numbers hold three digits after the point by chance (rounded, no trailing 0 kept:
    ``%g``) ends whole in ``0.25``."""
    rows = "".join(f"{x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in pts)
    head = (f"ply\nformat ascii 1.0\nelement vertex {len(pts)}\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n")
    (tmp_path / "mesh.ply").write_text(head + rows + "3 0 1 2")
    assert load_cloud(tmp_path / "mesh.ply").shape == (len(pts), 3)
    rounded = [f"{v:.3f}" for v in np.linspace(0.111, 0.999, 3 * 40)]  # three digits, none ending in 0
    rounded = [r if not r.endswith("0") else r[:-1] + "1" for r in rounded]
    text = "".join(f"{a},{b},{c}\n" for a, b, c in zip(*[iter(rounded)] * 3)) + "0.5,0.5,0.25"
    (tmp_path / "rounded.csv").write_text(text)
    assert load_cloud(tmp_path / "rounded.csv").shape == (41, 3)
