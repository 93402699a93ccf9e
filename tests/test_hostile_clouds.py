"""Hostile cloud files, init matrices and images met by the registration side: each refused in one line naming
the file (exit 2), a registration that cannot be trusted refused (exit 3) or marked, never returned as good."""

import importlib.util
import io
import json

import cv2
import numpy as np
import pytest
from _images import moved, rigid_about_centre, shapes_image

import pcreg
from pcreg.cli import main
from pcreg.cloud_reader import load_cloud
from pcreg.errors import InputError, RegistrationError
from pcreg.implementations import ImplementationError, Pinned, get


def _cloud(n=300, seed=0):
    return np.random.default_rng(seed).uniform(0, 10, (n, 3))


def _err_line(capfd) -> str:
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_a_text_cloud_of_many_columns_is_read_without_reserving_the_point_limit_for_each(tmp_path):
    # numpy reserved (limit + 1) rows of every column before reading: 2,000 columns under the default limit of 50
    # million points asked for 800 GB, and a file of 20 points was refused as "out of memory".
    wide = np.random.default_rng(0).uniform(0, 10, (20, 2000))
    names = ",".join(["x", "y", "z"] + [f"f{k}" for k in range(1997)])
    np.savetxt(tmp_path / "features.csv", wide, delimiter=",", header=names, comments="")
    np.testing.assert_array_equal(load_cloud(tmp_path / "features.csv"), wide[:, :3])
    # a file whose rows ran together (written without newlines) under a header of three names: one line of 2,000
    (tmp_path / "joined.csv").write_text("x,y,z\n" + ",".join(map(str, wide[0])) + "\n")
    with pytest.raises(InputError, match=r"joined.csv: .*2000 numbers a line under a first line of 3 names"):
        load_cloud(tmp_path / "joined.csv")


def test_a_npy_whose_header_declares_fewer_points_than_it_holds_is_refused(tmp_path):
    # numpy reads the points the header declares and leaves the rest unread: 400 of 500 were registered
    data = (io.BytesIO(), _cloud(500))
    np.save(data[0], data[1])
    raw = data[0].getvalue()
    (tmp_path / "fewer.npy").write_bytes(raw.replace(b"(500, 3)", b"(400, 3)"))
    with pytest.raises(InputError, match=r"fewer.npy: the .npy header declares \(400, 3\) float64 \(9600 bytes\), "
                                         r"the file holds 12000 bytes after it"):
        load_cloud(tmp_path / "fewer.npy")
    with open(tmp_path / "two.npy", "wb") as fh:  # two arrays saved one after the other
        np.save(fh, data[1])
        np.save(fh, data[1])
    with pytest.raises(InputError, match="arrays saved one after another"):
        load_cloud(tmp_path / "two.npy")


@pytest.mark.parametrize("path", [3, None, b"cloud.npy"])
def test_a_cloud_path_that_is_no_path_is_bad_input(path):
    with pytest.raises(InputError, match="path must be a path"):
        load_cloud(path)


@pytest.mark.parametrize("points, said", [(_cloud()[:1], "a single point"), (np.ones((50, 3)), "its 50 points coincide")])
def test_a_target_file_of_one_point_or_coincident_points_is_named(tmp_path, capfd, points, said):
    np.save(tmp_path / "t.npy", points)
    np.save(tmp_path / "s.npy", _cloud())
    assert main(["crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "s.npy")]) == 2
    assert _err_line(capfd).startswith(f"pcreg: error: {tmp_path / 't.npy'}: {said}: no correspondence distance")
    with pytest.raises(InputError, match=f"^{tmp_path / 't.npy'}: {said}"):
        pcreg.crosscheck(str(tmp_path / "t.npy"), str(tmp_path / "s.npy"))


def test_the_checks_of_a_cloud_cross_check_name_the_files_they_are_given():
    """The file in a cloud's refusal was found by reading "source:" or "target:" back off the message; the checks
    are given the files' names (None: an array, named by its role) and build their messages with them."""
    from pcreg.implementations.crosscheck import crosscheck_implementations

    coincident = np.ones((50, 3))
    with pytest.raises(InputError, match=r"^t\.ply: its 50 points coincide: no correspondence distance"):
        crosscheck_implementations(_cloud(), coincident, files=("s.ply", "t.ply"))
    with pytest.raises(InputError, match="^target: its 50 points coincide"):
        crosscheck_implementations(_cloud(), coincident, files=("s.ply", None))
    with pytest.raises(InputError, match=r"^s\.ply: 1 point\(s\) have NaN or inf coordinates"):
        crosscheck_implementations(np.vstack([_cloud(), [[np.nan, 0.0, 0.0]]]), _cloud(), files=("s.ply", "t.ply"))
    with pytest.raises(RegistrationError, match=r"^registration refused: s\.ply onto the target: no source point"):
        crosscheck_implementations(_cloud() + 1e4, _cloud(), files=("s.ply", None))
    with pytest.raises(InputError, match="files must be two file names"):
        crosscheck_implementations(_cloud(), _cloud(), files="s.ply")


def test_a_rigid_init_far_from_the_origin_is_taken_and_a_nan_one_is_named_so(tmp_path, capfd):
    # A georeferenced cloud's initial guess (a shift of 5e6) was refused as "singular or nearly so": the whole
    # matrix's condition number grows as the square of its translation.
    local = _cloud()
    T = np.eye(4)
    T[:3, 3] = [5e6, 3e6, 100.0]
    utm = local + T[:3, 3] + [0.05, -0.03, 0.02]
    r = pcreg.icp(local, utm, pcreg.ICPOptions(max_correspondence_distance=1.0), init=T)
    np.testing.assert_allclose(r.matrix[:3, 3] - T[:3, 3], [0.05, -0.03, 0.02], atol=1e-6)
    np.save(tmp_path / "t.npy", utm)
    np.save(tmp_path / "s.npy", local)
    np.savetxt(tmp_path / "init.txt", T)
    assert main(["crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "s.npy"), "--init", str(tmp_path / "init.txt"),
                 "--max-distance", "1", "--json"]) == 0
    assert json.loads(capfd.readouterr().out)["implementations"]["open3d"]["agrees"]
    singular = np.diag([1.0, 1.0, 0.0, 1.0])
    with pytest.raises(InputError, match="init is singular"):
        pcreg.icp(local, utm, init=singular)
    T[0, 0] = np.nan
    with pytest.raises(InputError, match="init must be a finite 4x4 matrix, got NaN or inf entries"):
        pcreg.icp(local, utm, init=T)



def test_an_init_matrix_written_with_commas_is_read_and_a_missing_number_is_refused(tmp_path, capfd):
    """A 4x4 initial guess saved as CSV (``numpy.savetxt(..., delimiter=",")``, a spreadsheet, ", " between the
    numbers) was refused as "not a text matrix"; it is read as the same matrix written with spaces. An empty field
    between two commas is still refused, naming the file."""
    from pcreg.text_files import read_text_matrix

    T = np.eye(4)
    T[:3, 3] = [0.5, -0.25, 1e-3]
    np.savetxt(tmp_path / "spaces.txt", T)
    np.savetxt(tmp_path / "commas.csv", T, delimiter=",")
    (tmp_path / "spaced.txt").write_text("\n".join(", ".join(repr(float(v)) for v in row) for row in T) + "\n")
    # a comment's commas say nothing of how the numbers are separated
    (tmp_path / "noted.txt").write_text("# x, y, z and 1\n" + (tmp_path / "spaces.txt").read_text())
    for name in ("commas.csv", "spaced.txt", "noted.txt"):
        np.testing.assert_array_equal(read_text_matrix(tmp_path / name), read_text_matrix(tmp_path / "spaces.txt"))
    target = _cloud()
    np.save(tmp_path / "t.npy", target)
    np.save(tmp_path / "s.npy", target - T[:3, 3])
    assert main(["crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "s.npy"), "--init", str(tmp_path / "commas.csv"),
                 "--max-distance", "1", "--json"]) == 0
    assert json.loads(capfd.readouterr().out)["implementations"]["open3d"]["agrees"]
    (tmp_path / "gap.csv").write_text("1,,0,0\n0,1,0,0\n0,0,1,0\n0,0,0,1\n")
    assert main(["crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "s.npy"), "--init", str(tmp_path / "gap.csv")]) == 2
    line = _err_line(capfd)
    assert "gap.csv: not a text matrix" in line, line

def _animated(tmp_path, name, **save):
    from PIL import Image

    frames = [Image.fromarray(shapes_image(seed=k)) for k in range(3)]
    frames[0].save(tmp_path / name, save_all=True, append_images=frames[1:], **save)
    return tmp_path / name


@pytest.mark.parametrize("name, save, images", [("a.png", {}, 3), ("d.png", {"default_image": True}, 3),
                                                ("a.webp", {"lossless": True}, 3)])
def test_an_animated_png_or_webp_is_refused_as_a_multi_page_tiff_is(tmp_path, capfd, name, save, images):
    # OpenCV decoded its first image alone, which was registered as the file
    animated = _animated(tmp_path, name, **save)
    cv2.imwrite(str(tmp_path / "ref.png"), shapes_image()[:, :, ::-1])
    assert main(["register", str(tmp_path / "ref.png"), str(animated)]) == 2
    kind = "PNG" if name.endswith(".png") else "WebP"
    assert _err_line(capfd) == (f"pcreg: error: {animated}: an animated {kind} of {images} images, of which pcreg would "
                                "read the first alone; save the one meant as an image of its own (Pillow's "
                                "ImageSequence, or ffmpeg)")
    with pytest.raises(InputError, match="an animated"):
        pcreg.load_image(animated)


@pytest.mark.parametrize("name", ["open3d", "open3d-tensor", "small_gicp", "kiss-icp"])
def test_an_implementation_called_directly_refuses_a_guess_that_is_no_rigid_transform(name):
    # Open3D and small_gicp returned the shear they were given, moved, as their converged rigid result
    if get(name).missing():
        pytest.skip(get(name).missing())
    cloud = _cloud()
    shear = np.eye(4)
    shear[0, 1] = 0.3
    with pytest.raises(InputError, match="init: its rotation block is not orthonormal .*every implementation runs the "
                                         "rigid ICP"):
        get(name).run(Pinned(cloud + 0.05, cloud, shear, 1.0))


@pytest.mark.parametrize("changes, said", [
    ({"init": np.diag([np.nan, 1, 1, 1])}, "pinned: init has NaN or inf entries"),  # KISS-ICP's Sophus aborted
    ({"source": np.full((10, 3), np.nan)}, "source: 10 point"),
    ({"source": np.zeros((10, 2)), "init": np.eye(3)}, "pinned: source is 2-D but target is 3-D"),
    ({"init": np.eye(3)}, "pinned: init must be a 4x4 matrix for 3-D clouds, got shape \\(3, 3\\)"),
    ({"max_correspondence_distance": -1.0}, "max_correspondence_distance must be > 0"),  # Open3D's RuntimeError
    ({"max_iterations": 0}, "max_iterations must be in 1..100000"),
])
def test_pinned_inputs_are_checked_when_made(changes, said):
    cloud = _cloud()
    given = {"source": cloud + 0.05, "target": cloud, "init": np.eye(4), "max_correspondence_distance": 1.0, **changes}
    with pytest.raises(InputError, match=said):
        Pinned(**given)


def test_an_implementation_on_points_that_leave_the_rotation_free_marks_its_pose_and_the_reference_refuses():
    line = np.column_stack([np.linspace(0, 10, 200), np.zeros(200), np.zeros(200)])
    pinned = Pinned(line + [0.1, 0.1, 0.0], line, np.eye(4), 1.0)
    with pytest.raises(RegistrationError, match="collinear"):
        get("reference").run(pinned)
    r = get("open3d").run(pinned)
    assert r.info["unconstrained"] == "source: the points are collinear: they cannot determine a rigid transform"
    assert r.trusted is False
    good = get("open3d").run(Pinned(_cloud() + 0.05, _cloud(), np.eye(4), 1.0))
    assert "unconstrained" not in good.info and good.trusted


def test_a_cpd_that_collapses_the_cloud_is_an_implementation_error():
    # pycpd's scale fell to 0 on coincident points: a singular matrix returned as its converged result
    if get("pycpd").missing():
        pytest.skip(get("pycpd").missing())
    ones = np.ones((50, 3))
    with pytest.raises(ImplementationError, match="determinant 0: a collapse of the cloud"):
        get("pycpd").run(Pinned(ones + 0.1, ones, np.eye(4), 1.0))


@pytest.mark.skipif(importlib.util.find_spec("small_gicp") is None, reason="small_gicp is not installed")
def test_what_a_library_prints_goes_into_its_row_not_onto_the_terminal(tmp_path, capfd):
    cloud = _cloud(10)
    np.save(tmp_path / "t.npy", cloud)
    np.save(tmp_path / "s.npy", cloud)
    assert main(["crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "s.npy"), "--with", "reference,small_gicp"]) == 0
    out, err = capfd.readouterr()
    assert err == ""
    assert "its library said: warning: target point cloud is too small. |target|=10" in out


def test_an_image_cross_check_of_a_mirror_image_marks_both_poses_and_exits_3(tmp_path, capfd):
    # Both backends' poses were listed as converged and agreeing, exit 0: register refuses the pair
    ref = shapes_image()
    mov = moved(ref, rigid_about_centre(ref.shape, 5.0, 3.0, -2.0))
    report = pcreg.crosscheck(ref, mov[:, ::-1].copy())
    assert report.refused.startswith("the moving image is a mirror image of the reference")
    assert report.to_dict()["refused"] == report.refused
    assert pcreg.crosscheck(ref, mov).refused is None
    cv2.imwrite(str(tmp_path / "ref.png"), ref[:, :, ::-1])
    cv2.imwrite(str(tmp_path / "mirror.png"), mov[:, ::-1, ::-1])
    assert main(["crosscheck", str(tmp_path / "ref.png"), str(tmp_path / "mirror.png")]) == 3
    out, err = capfd.readouterr()
    assert "refused, not trusted: the moving image is a mirror image" in out
    assert err.startswith("pcreg: registration refused: pcreg register refuses these images: the moving image is a "
                          "mirror image") and len(err.strip().splitlines()) == 1


def test_an_image_cross_check_of_a_refused_pair_searches_once_with_the_reference(monkeypatch):
    """A refused pair's reference pose was the search run a second time with the test off: one search now gives
    the pose and the refusal, the same pose ``register`` returns with the test off and the refusal it raises."""
    from pcreg.implementations.crosscheck import CROSSCHECK_REGISTRATION
    from pcreg.registration import api
    from pcreg.registration.config import DEFAULT_MIN_INLIER_RATIO

    ref = shapes_image()
    mirror = moved(ref, rigid_about_centre(ref.shape, 5.0, 3.0, -2.0))[:, ::-1].copy()
    searched = []
    search = api._search

    def counted(reference, moving, config, init, **kw):
        searched.append(config.backend)
        return search(reference, moving, config, init, **kw)

    monkeypatch.setattr(api, "_search", counted)
    report = pcreg.crosscheck(ref, mirror)
    assert sorted(searched) == ["open3d", "reference"]
    monkeypatch.setattr(api, "_search", search)
    config = CROSSCHECK_REGISTRATION.replace(model_check=False)
    untested = pcreg.register(ref, mirror, config=config, backend="reference")
    assert np.array_equal(report.reference.matrix, untested.matrix)
    assert report.reference.iterations == untested.iterations
    with pytest.raises(RegistrationError) as refused:
        pcreg.register(ref, mirror, config=config.replace(min_inlier_ratio=DEFAULT_MIN_INLIER_RATIO), backend="reference")
    assert report.refused == str(refused.value).removeprefix("registration refused: ")
    pose, refusal = api.register_judged(ref, mirror, config=config.replace(min_inlier_ratio=DEFAULT_MIN_INLIER_RATIO),
                                        backend="reference")
    assert str(refusal) == str(refused.value) and np.array_equal(pose.matrix, untested.matrix)


@pytest.mark.parametrize("order, said", [
    ("z y x", "its vertex properties x, y, z come in the order z, y, x: Open3D's reader, which reads PLY, takes z for "
              "the last of them and fails on this order"),
    ("x y z nz ny nx", "its vertex properties nx, ny, nz come in the order nz, ny, nx"),
    ("x y z x", "PLY vertices declare the x property twice"),
])
def test_a_ply_whose_vertex_properties_open3d_reads_wrongly_is_refused_saying_why(tmp_path, order, said):
    # Open3D's reader moves to the next point after z: "Read PLY failed: unable to read file" (a duplicate x: one of
    # the two, its own choice)
    names = order.split()
    values = _cloud(50).astype("<f4")
    columns = np.column_stack([values[:, "xyz".index(n[-1])] for n in names])
    head = "ply\nformat binary_little_endian 1.0\nelement vertex 50\n" + "".join(f"property float {n}\n" for n in names)
    (tmp_path / "c.ply").write_bytes((head + "end_header\n").encode() + columns.astype("<f4").tobytes())
    with pytest.raises(InputError, match=f"c.ply: {said}"):
        load_cloud(tmp_path / "c.ply")
    names = ["y", "x", "z"]  # z after x and y: read, in any order of x and y
    head = "ply\nformat binary_little_endian 1.0\nelement vertex 50\n" + "".join(f"property float {n}\n" for n in names)
    (tmp_path / "yxz.ply").write_bytes((head + "end_header\n").encode() + values[:, [1, 0, 2]].copy().tobytes())
    np.testing.assert_array_equal(load_cloud(tmp_path / "yxz.ply"), values.astype(np.float64))


@pytest.mark.parametrize("text, said", [("1 0 0 0\n0 1 0 0\n0 0 1 0\n", "a 3x4 pose without its last row (add the row 0 0 0 1)"),
                                        ("1 0 0 0 0 1 0 0 0 0 1 0\n", "one line of 12 numbers, as KITTI writes a pose?")])
def test_an_init_pose_without_its_last_row_says_what_to_add(tmp_path, capfd, text, said):
    """A 3-D pose written as its top 3x4 (KITTI's poses, many tools' outputs), in rows or on one line: refused as
    "must be a finite 4x4 matrix, got shape (3, 4)", which left the user to guess what the shape was missing."""
    target = _cloud()
    np.save(tmp_path / "t.npy", target)
    np.save(tmp_path / "s.npy", target + 0.01)
    (tmp_path / "pose.txt").write_text(text)
    assert main(["crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "s.npy"), "--init", str(tmp_path / "pose.txt")]) == 2
    line = _err_line(capfd)
    assert "pose.txt: the initial guess must be a finite 4x4 matrix" in line and said in line, line


def test_an_init_pose_that_is_a_reflection_is_said_of_its_file_as_register_says_it(tmp_path, capfd):
    """``crosscheck --init FILE`` and ``register --init FILE`` refuse a reflection in one wording: the file, then what it
    was for (crosscheck's read "pose.txt: it is a reflection", register's "pose.txt: the initial guess: it is ...")."""
    target = _cloud()
    np.save(tmp_path / "t.npy", target)
    np.save(tmp_path / "s.npy", target + 0.01)
    np.savetxt(tmp_path / "pose.txt", np.diag([-1.0, 1.0, 1.0, 1.0]))
    assert main(["crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "s.npy"), "--init", str(tmp_path / "pose.txt")]) == 2
    assert _err_line(capfd).startswith(f"pcreg: error: {tmp_path / 'pose.txt'}: the initial guess: it is a reflection")
    image = shapes_image(96, 128, seed=3)
    cv2.imwrite(str(tmp_path / "ref.png"), image)
    cv2.imwrite(str(tmp_path / "mov.png"), image)
    np.savetxt(tmp_path / "pose2.txt", np.diag([-1.0, 1.0, 1.0]))
    assert main(["register", str(tmp_path / "ref.png"), str(tmp_path / "mov.png"), "--model", "rigid",
                 "--init", str(tmp_path / "pose2.txt")]) == 2
    assert _err_line(capfd).startswith(f"pcreg: error: {tmp_path / 'pose2.txt'}: the initial guess: it is a reflection")


@pytest.mark.parametrize("text, where", [("# x y z\n1 2 3\n4 5 6\n7 8 10\n", "its first point line ('# x y z')"),
                                         ("1 2 3\n//scan 2\n4 5 6\n7 8 10\n", "point line 2 ('//scan 2')")])
def test_a_text_cloud_with_comment_lines_is_told_apart_from_a_damaged_one(tmp_path, text, where):
    """A .xyz file whose lines include a comment (numpy.savetxt's header, CloudCompare's //): refused saying it is a
    comment and where pcreg reads one, not "damaged"; the same points as a .txt file are read, the comment skipped."""
    path = tmp_path / "c.xyz"
    path.write_text(text)
    with pytest.raises(InputError) as err:
        load_cloud(path)
    assert f"{where} is a comment" in str(err.value) and "damaged" not in str(err.value)
    if text.startswith("#"):
        txt = tmp_path / "c.txt"
        txt.write_text(text)
        np.testing.assert_array_equal(load_cloud(txt), [[1, 2, 3], [4, 5, 6], [7, 8, 10]])
    # a .pts file (read by pcreg, not Open3D): the comment said before its count, which the comment line throws off
    pts = tmp_path / "c.pts"
    pts.write_text("3\n" + text)
    with pytest.raises(InputError) as err:
        load_cloud(pts)
    assert f"{where} is a comment, which a .pts file does not hold;" in str(err.value)


def _grid(shift=(0.0, 0.0, 0.0)):
    u, v = np.meshgrid(np.linspace(0, 1, 40), np.linspace(0, 1, 40))
    return (np.c_[u.ravel(), v.ravel(), 0.2 * np.sin(6 * u.ravel()) * np.cos(4 * v.ravel())] + shift).astype("<f4")


def _binary_ply(path, points, count, after=""):
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {count}\nproperty float x\nproperty float y\n"
            f"property float z\n{after}end_header\n")
    path.write_bytes(head.encode() + points.tobytes())
    return path


@pytest.mark.parametrize("count", ["16_00", "1_600", "+1600", "0x640"])
def test_a_header_count_python_reads_and_c_does_not_is_refused(tmp_path, count):
    """A PLY or PCD count written ``16_00``: Python's ``int`` read 1600 and pcreg's checks passed, where Open3D's
    reader stops at the ``_`` and read 16 points (a PCD's SIZE ``0_4``: garbage points). Refused naming the file;
    ``+1600`` is a number C reads whole, and is read."""
    ply = _binary_ply(tmp_path / "c.ply", _grid(), count)
    pcd = tmp_path / "c.pcd"
    pcd.write_bytes((f"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {count}\nHEIGHT 1\n"
                     f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {count}\nDATA binary\n").encode() + _grid().tobytes())
    for path in (ply, pcd):
        if count == "+1600":
            assert load_cloud(path).shape == (1600, 3)
            continue
        with pytest.raises(InputError, match=rf"^{path}: (bad PLY element line|damaged PCD header)"):
            load_cloud(path)


@pytest.mark.parametrize("after", ["element face 1\nproperty list uchar int vertex_indices\n",
                                   "element extra 1\nproperty float w\n"])
def test_a_binary_ply_whose_vertex_count_lies_low_before_another_element_is_refused(tmp_path, after):
    """1,600 vertices under a header of 1,000 followed by a face (or a fixed) element: the rest of the vertices were
    read as that element and 1,000 points registered, exit 0. The elements are walked to their end as a reader
    walks them: they end 7,000 bytes before the file does. The same file with its count right is read."""
    with pytest.raises(InputError, match=r"declares 1000 vertices, and its elements end \d+ bytes before the file"):
        load_cloud(_binary_ply(tmp_path / "low.ply", _grid(), 1000, after))
    face = bytes([3]) + np.array([0, 1, 2], "<i4").tobytes() if "face" in after else np.float32(1).tobytes()
    good = _binary_ply(tmp_path / "good.ply", _grid(), 1600, after)
    good.write_bytes(good.read_bytes() + face)
    assert load_cloud(good).shape == (1600, 3)
    cut = good.read_bytes()[:-2]  # the last element cut short
    (tmp_path / "cut.ply").write_bytes(cut)
    with pytest.raises(InputError, match=r"cut.ply: truncated or damaged PLY"):
        load_cloud(tmp_path / "cut.ply")


def test_a_cloud_so_small_that_its_squared_distances_underflow_is_refused():
    """A cloud 1e-200 across turned 10 degrees came back unturned, inlier RMSE 0, fitness 1, trusted: its squared
    distances underflow to 0. Refused naming its span; one 1e-135 across is registered."""
    rng = np.random.default_rng(3)
    unit = rng.uniform(-1, 1, (500, 3))
    a = np.deg2rad(10)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    with pytest.raises(InputError, match=r"^source: the cloud spans 2.28e-200, under 1e-140"):
        pcreg.icp(unit @ R * 1e-200, unit * 1e-200)
    # its stopping rule's changes are absolute (Open3D's): at this scale, none
    r = pcreg.icp(unit @ R * 1e-135, unit * 1e-135, pcreg.ICPOptions(relative_fitness=0, relative_rmse=0))
    np.testing.assert_allclose(r.matrix[:3, :3], R, atol=1e-6)


def test_a_byte_order_mark_is_named_in_a_ply_and_read_past_in_a_text_matrix(tmp_path):
    """An editor's UTF-8 byte-order mark: a PLY was refused as "no 'ply' magic" (it has one, after the mark), and an
    --init matrix as numpy's "could not convert string 'ï»¿1'". The PLY's refusal names the mark; the matrix,
    text, is read past it."""
    from pcreg.text_files import read_text_matrix

    ply = tmp_path / "bom.ply"
    ply.write_bytes(b"\xef\xbb\xbfply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                    b"property float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n")
    with pytest.raises(InputError, match="starts with a UTF-8 byte-order mark"):
        load_cloud(ply)
    init = tmp_path / "init.txt"
    init.write_bytes(b"\xef\xbb\xbf1 0 2\r\n0 1 3\r\n0 0 1\r\n")
    np.testing.assert_array_equal(read_text_matrix(init), [[1, 0, 2], [0, 1, 3], [0, 0, 1]])


@pytest.mark.parametrize("mark, name", [("\u00a0", "NO-BREAK SPACE"), ("\u2212", "MINUS SIGN")])
def test_a_word_processors_space_or_minus_in_a_text_cloud_is_named(tmp_path, mark, name):
    """A no-break space between two numbers, or a minus sign for '-', was refused as "its first line
    ('0.63\ufffd\ufffd0.27,0.04') names no x and y columns": the line quoted was rebuilt, not the file's, and the
    cause was another. The character is named; a header of words not ASCII is quoted as written."""
    path = tmp_path / "cloud.txt"
    path.write_text(f"0.63{mark}0.27 0.04\n0.1 0.2 0.3\n0.4 0.5 0.6\n", encoding="utf-8")
    with pytest.raises(InputError, match=rf"^{path}: its first line holds {name} \(U\+"):
        load_cloud(path)
    words = tmp_path / "words.csv"
    words.write_text("Längengrad,Breitengrad\n1,2\n3,4\n5,6\n", encoding="utf-8")
    with pytest.raises(InputError, match=r"its first line \('Längengrad,Breitengrad'\) names no x and y columns"):
        load_cloud(words)


def test_a_ply_of_two_vertex_elements_is_refused_not_read_in_half(tmp_path):
    """A PLY of two vertex elements (25 points and 25): the first 25 alone were read and registered, exit 0."""
    points = np.random.default_rng(0).uniform(0, 1, (50, 3))
    element = "element vertex 25\nproperty float x\nproperty float y\nproperty float z\n"
    path = tmp_path / "two.ply"
    path.write_text("ply\nformat ascii 1.0\n" + 2 * element + "end_header\n" + "".join(f"{x} {y} {z}\n" for x, y, z in points))
    with pytest.raises(InputError, match=rf"^{path}: the PLY header declares 2 vertex elements \(25, 25 points\)"):
        load_cloud(path)
    path.write_text("ply\nformat ascii 1.0\n" + element.replace("25", "50") + "end_header\n"
                    + "".join(f"{x} {y} {z}\n" for x, y, z in points))
    assert load_cloud(path).shape == (50, 3)


def test_a_pcd_naming_a_field_twice_or_a_keyword_twice_is_refused(tmp_path):
    """FIELDS x y z x: pcreg's ASCII reader took the first x, Open3D's binary reader the last, so the same cloud
    read two ways; two FIELDS lines, the last taken. Refused naming the file, as a PLY's property named twice is."""
    head = "VERSION 0.7\nFIELDS x y z x\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 3\nHEIGHT 1\nPOINTS 3\n"
    (tmp_path / "twice.pcd").write_text(head + "DATA ascii\n" + "0 0 0 5\n1 0 0 6\n0 1 0 5\n")
    with pytest.raises(InputError, match=r"twice.pcd: its PCD header names the field x twice"):
        load_cloud(tmp_path / "twice.pcd")
    lines = head.replace("FIELDS x y z x", "FIELDS x y z w\nFIELDS x y w z")
    (tmp_path / "two.pcd").write_text(lines + "DATA ascii\n" + "0 0 0 5\n1 0 0 6\n0 1 0 5\n")
    with pytest.raises(InputError, match=r"two.pcd: its PCD header has two FIELDS lines"):
        load_cloud(tmp_path / "two.pcd")


def test_a_cross_check_of_an_image_against_a_cloud_names_both(tmp_path, capfd):
    """"cannot cross-check image against cloud" named neither file."""
    cv2.imwrite(str(tmp_path / "ref.png"), shapes_image())
    np.save(tmp_path / "mov.npy", _cloud())
    assert main(["crosscheck", str(tmp_path / "ref.png"), str(tmp_path / "mov.npy")]) == 2
    assert _err_line(capfd) == (f"pcreg: error: {tmp_path / 'mov.npy'}: a cloud, and {tmp_path / 'ref.png'} an image: "
                                "give two images or two clouds")
    with pytest.raises(InputError, match="^moving: an image, and reference a cloud"):
        pcreg.crosscheck(_cloud(), shapes_image())


def test_an_ascii_ply_value_open3d_cannot_read_is_named_by_vertex_and_property(tmp_path):
    """An ASCII PLY holding ``inf`` (or 1e39 in a float property): "cannot read point cloud (Open3D: Read PLY failed:
    unable to read file: ...)", saying nothing of what. RPly's own line names the vertex and the property."""
    rows = [f"{i} {i % 7} {i % 3}" for i in range(20)]
    for value, at in (("inf", 7), ("1e39", 3)):
        body = rows.copy()
        body[at] = f"{at} {at % 7} {value}"
        path = tmp_path / f"v{at}.ply"
        path.write_text("ply\nformat ascii 1.0\nelement vertex 20\nproperty float x\nproperty float y\nproperty float z\n"
                        "end_header\n" + "\n".join(body) + "\n")
        with pytest.raises(InputError, match=rf"^{path}: cannot read point cloud \(Open3D: RPly: Error reading 'z' of "
                                             rf"'vertex' number {at}\)"):
            load_cloud(path)


@pytest.mark.parametrize("suffix", [".csv", ".txt"])
def test_a_text_cloud_in_utf16_or_with_carriage_returns_alone_says_so(tmp_path, suffix):
    """Both were refused as "its first line ('0.01,0.02,0.0\\r0.0356...') names no x and y columns", which they do
    not need to: they are a UTF-16 file and a file of classic Mac OS line ends."""
    text = "".join(f"{x},{x % 3},{x % 5}\n" for x in range(20))
    (tmp_path / f"u{suffix}").write_bytes(text.encode("utf-16"))
    (tmp_path / f"r{suffix}").write_bytes(text.replace("\n", "\r").encode())
    (tmp_path / f"w{suffix}").write_bytes(text.replace("\n", "\r\n").encode())
    with pytest.raises(InputError, match=rf"u{suffix}: it is UTF-16 text"):
        load_cloud(tmp_path / f"u{suffix}")
    with pytest.raises(InputError, match=rf"r{suffix}: its lines end in a carriage return alone"):
        load_cloud(tmp_path / f"r{suffix}")
    assert load_cloud(tmp_path / f"w{suffix}").shape == (20, 3)


@pytest.mark.parametrize("mark, name", [("\u00a0", "NO-BREAK SPACE"), ("\u2212", "MINUS SIGN")])
@pytest.mark.parametrize("kind", ["header.csv", "header.txt", ".xyz"])
def test_a_word_processors_character_below_a_header_or_in_an_xyz_is_named(tmp_path, mark, name, kind):
    """The same character on a line under a header ('x,y,z'), or in a .xyz file, was quoted garbled
    ("'0.1257,\ufffd\ufffd\ufffd0.132' is not a number"): the line is quoted as written and the character named."""
    sep = "," if kind == "header.csv" else " "
    body = f"0.63{sep}{mark}0.27{sep}0.04\n0.1{sep}0.2{sep}0.3\n" if mark == "\u2212" else f"0.63{mark}0.27{sep}0.04\n0.1{sep}0.2{sep}0.3\n"
    path = tmp_path / ("cloud.xyz" if kind == ".xyz" else f"cloud.{kind.split('.')[1]}")
    path.write_text(("" if kind == ".xyz" else f"x{sep}y{sep}z\n") + body, encoding="utf-8")
    with pytest.raises(InputError, match=rf"{name} \(U\+") as info:
        load_cloud(path)
    said = str(info.value)  # the line quoted as written: a minus sign as itself, a no-break space as '\xa0'
    assert "\ufffd" not in said and (mark in said or "\\xa0" in said)
