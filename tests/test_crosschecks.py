import json

import numpy as np
import pytest

import pcreg
from pcreg import transforms as tf
from pcreg.implementations.crosscheck import load_cloud
from pcreg.errors import InputError

from _images import moved, rigid_about_centre, shapes_image


def relative(a, b):
    return np.max(np.abs(a - b)) / max(1.0, np.max(np.abs(a)))


@pytest.mark.parametrize("dim, model", [(2, "rigid"), (2, "similarity"), (3, "rigid"), (3, "similarity")])
def test_backends_agree_on_synthetic_clouds(dim, model):
    rng = np.random.default_rng(dim)
    target = rng.uniform(-10, 10, (3000, dim))
    T = np.eye(dim + 1)
    a = np.deg2rad(4.0)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:dim, dim] = 0.3
    if model == "similarity":
        T[:dim, :dim] *= 1.02
    source = tf.apply(np.linalg.inv(T), target) + rng.normal(scale=0.02, size=target.shape)
    kw = dict(model=model, max_correspondence_distance=1.0, max_iteration=50)
    ref = pcreg.icp(source, target, pcreg.ICPOptions(backend="reference", **kw))
    o3d = pcreg.icp(source, target, pcreg.ICPOptions(backend="open3d", **kw))
    assert relative(ref.matrix, o3d.matrix) < 1e-6
    assert ref.iterations == o3d.iterations
    assert ref.converged == o3d.converged
    assert ref.fitness == pytest.approx(o3d.fitness, abs=1e-12)
    assert ref.inlier_rmse == pytest.approx(o3d.inlier_rmse, rel=1e-6)


def test_backends_agree_iteration_by_iteration():
    rng = np.random.default_rng(7)
    target = rng.uniform(-10, 10, (1000, 2))
    source = tf.apply(np.linalg.inv(tf.rigid2d(6, 0.5, -0.4)), target)
    seen = {"reference": [], "open3d": []}
    for backend in seen:
        pcreg.icp(source, target, pcreg.ICPOptions(backend=backend, max_correspondence_distance=2.0, max_iteration=20),
                  callback=lambda it: seen[it.backend].append(it))
    assert len(seen["reference"]) == len(seen["open3d"]) > 3
    for a, b in zip(seen["reference"], seen["open3d"]):
        assert relative(a.matrix, b.matrix) < 1e-9
        assert a.fitness == pytest.approx(b.fitness, abs=1e-12)
        np.testing.assert_array_equal(a.target_indices, b.target_indices)


def test_crosscheck_of_two_clouds_takes_its_stopping_rule_from_the_config():
    rng = np.random.default_rng(0)
    target = rng.uniform(-10, 10, (800, 2))
    source = tf.apply(np.linalg.inv(tf.rigid2d(5, 0.3, -0.2)), target)
    d = pcreg.crosscheck(source, target).to_dict()
    assert d["kind"] == "clouds"
    assert {k: d["settings"][k] for k in ("max_iterations", "relative_fitness", "relative_rmse")} == \
        {"max_iterations": 30, "relative_fitness": 1e-6, "relative_rmse": 1e-6}
    assert d["implementations"]["open3d"]["agrees"] is True


def test_a_crosscheck_with_no_correspondence_at_the_initial_pose_is_refused(tmp_path, capsys):
    """Clouds 1e4 target diagonals apart: every ICP stops at the identity with fitness 0, which read as
    implementations that converged and agree; the cross-check is refused (exit 3), and runs with an --init
    that brings them together."""
    from pcreg.cli import main
    from pcreg.errors import RegistrationError

    rng = np.random.default_rng(0)
    target = rng.uniform(0, 10, (500, 3))
    source = target + 1e5
    with pytest.raises(RegistrationError, match="no source point lies within the correspondence distance"):
        pcreg.crosscheck(source, target)
    np.save(tmp_path / "s.npy", source)
    np.save(tmp_path / "t.npy", target)
    assert main(["crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "s.npy")]) == 3
    err = capsys.readouterr().err
    assert f"registration refused: {tmp_path / 's.npy'} onto {tmp_path / 't.npy'}: no source point" in err
    assert err.rstrip().endswith("(give --init, or a larger --max-distance)")
    init = np.eye(4)
    init[:3, 3] = -1e3  # an --init still far off: another one is asked for, not "give --init"
    np.savetxt(tmp_path / "init.txt", init)
    assert main(["crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "s.npy"), "--init", str(tmp_path / "init.txt")]) == 3
    assert capsys.readouterr().err.rstrip().endswith("(another --init, or a larger --max-distance)")
    init[:3, 3] = -1e5
    np.savetxt(tmp_path / "init.txt", init)
    assert main(["crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "s.npy"), "--init", str(tmp_path / "init.txt")]) == 0


def test_a_crosscheck_whose_pairs_at_the_initial_pose_do_not_determine_a_rotation_is_refused(tmp_path, capsys):
    """One source point within the gate of a 3-D target: pcreg's reference stopped where it started while
    Open3D moved by a rotation one pair cannot determine, and the command exited 0; it is refused (exit 3),
    naming how many points were within the gate and how many a rigid motion needs."""
    from pcreg.cli import main

    rng = np.random.default_rng(0)
    target = rng.random((400, 3))
    t = np.radians(30)
    source = target @ np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]]).T + [0.3, 0.1, 0]
    np.savetxt(tmp_path / "s.xyz", source)
    np.savetxt(tmp_path / "t.xyz", target)
    assert main(["crosscheck", str(tmp_path / "t.xyz"), str(tmp_path / "s.xyz")]) == 3
    err = capsys.readouterr().err
    assert (f"registration refused: {tmp_path / 's.xyz'} onto {tmp_path / 't.xyz'}: 1 source point of 400 lies within "
            "the correspondence distance") in err
    assert "a rigid motion in 3-D needs 3" in err
    assert main(["crosscheck", str(tmp_path / "t.xyz"), str(tmp_path / "s.xyz"), "--max-distance", "0.05"]) == 0


def test_a_suite_case_with_no_correspondence_is_a_refused_row_and_the_others_run():
    from pcreg.implementations.suite import Case, run_suite

    rng = np.random.default_rng(1)
    target = rng.uniform(0, 10, (300, 3))
    near = Case(target + 0.05, target, np.eye(4), 1.0, 30, 1e-6, 1e-6, name="near")
    far = Case(target + 1e5, target, np.eye(4), 1.0, 30, 1e-6, 1e-6, name="far")
    rows = run_suite([far, near], ["reference", "open3d"])
    assert [(r["case"], r["implementation"], r["status"]) for r in rows] == [
        ("far", "reference", "refused"), ("near", "reference", "ok"), ("near", "open3d", "ok")]
    assert "no source point lies within" in rows[0]["error"]


def test_crosscheck_images_agree():
    ref = shapes_image()
    mov = moved(ref, rigid_about_centre(ref.shape, 35.0, 10.0, -6.0))
    report = pcreg.crosscheck(ref, mov)
    d = report.to_dict()
    assert d["kind"] == "images"
    assert d["max_corner_disagreement_px"] < 1e-6
    assert report.reference.iterations == report.open3d.iterations > 0
    assert d["reference_seconds"] > 0 and d["open3d_seconds"] > 0


@pytest.mark.data
def test_real_scan_pair_both_backends_land_on_the_ground_truth(shared_data):
    scans = shared_data / "scans"
    source, target = load_cloud(scans / "source.ply"), load_cloud(scans / "target.ply")
    truth = np.loadtxt(scans / "T_target_source.txt")
    kw = dict(model="rigid", schedule=pcreg.VoxelSchedule((1.0, 0.5, 0.25)), max_iteration=30, relative_fitness=1e-6,
              relative_rmse=1e-6)
    ref = pcreg.icp(source, target, pcreg.ICPOptions(backend="reference", **kw))
    o3d = pcreg.icp(source, target, pcreg.ICPOptions(backend="open3d", **kw))
    assert relative(ref.matrix, o3d.matrix) < 1e-6
    for r in (ref, o3d):
        assert np.linalg.norm(r.matrix[:3, 3] - truth[:3, 3]) < 0.05
        assert tf.rotation_disagreement_deg(r.matrix, truth) < 0.25


def test_load_cloud_formats_and_errors(tmp_path):
    pts = np.random.default_rng(0).normal(size=(50, 3))
    np.save(tmp_path / "a.npy", pts)
    np.savetxt(tmp_path / "a.xyz", pts)
    np.testing.assert_allclose(load_cloud(tmp_path / "a.npy"), pts)
    np.testing.assert_allclose(load_cloud(tmp_path / "a.xyz"), pts, atol=1e-6)
    with pytest.raises(InputError, match="no such file"):
        load_cloud(tmp_path / "missing.ply")
    (tmp_path / "bad.ply").write_text("not a ply")
    with pytest.raises(InputError, match="no points"):
        load_cloud(tmp_path / "bad.ply")
    (tmp_path / "a.las").write_text("1 2 3\n")
    with pytest.raises(InputError, match="unknown point-cloud format"):
        load_cloud(tmp_path / "a.las")
    bad = pts.copy()
    bad[3, 1] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    with pytest.raises(InputError, match="NaN"):
        load_cloud(tmp_path / "nan.npy")


def test_a_ply_that_holds_more_vertices_than_its_header_declares_is_refused(tmp_path):
    """Open3D reads the count the header declares and drops the rest silently: a header that lies low is
    refused, ASCII and binary; a trailing newline after the data is no vertex and is read."""
    import open3d as o3d

    pts = np.random.default_rng(0).normal(size=(300, 3))
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    for ascii_ in (True, False):
        path = tmp_path / f"c{ascii_}.ply"
        o3d.io.write_point_cloud(str(path), cloud, write_ascii=ascii_)
        with open(path, "ab") as fh:
            fh.write(b"\n")
        assert load_cloud(path).shape == (300, 3)
        data = path.read_bytes()
        path.write_bytes(data.replace(b"element vertex 300", b"element vertex 100", 1))
        with pytest.raises(InputError, match=f"{path.name}: the PLY header declares"):
            load_cloud(path)


def test_crosscheck_refuses_an_image_against_a_cloud(tmp_path):
    np.save(tmp_path / "a.npy", np.random.default_rng(0).normal(size=(50, 3)))
    import cv2

    cv2.imwrite(str(tmp_path / "b.png"), shapes_image())
    with pytest.raises(InputError, match="two images or two clouds"):
        pcreg.crosscheck(tmp_path / "b.png", tmp_path / "a.npy")


def test_transforms_that_the_rigid_icp_cannot_hold_are_refused_as_its_start_or_truth(tmp_path, capsys):
    """A reflection, a scale or a projection as the start of a rigid ICP came back as its "rigid" result (exit
    0); a 3x3 truth of 3-D clouds was an internal error; a start written with three decimals, as Open3D's own
    test of its ICP gives one, still runs."""
    from pcreg.cli import main
    from pcreg.implementations.suite import Case, export_suite

    rng = np.random.default_rng(2)
    target = rng.uniform(0, 1, (300, 3))
    source = target + 0.01
    for bad, said in ((np.diag([-1.0, 1, 1, 1]), "reflection"), (np.diag([2.0, 2, 2, 1]), "not orthonormal"),
                      (np.array([[1.0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0.5, 0, 0, 1]]), "last row")):
        with pytest.raises(InputError, match=said):
            pcreg.icp(source, target, init=bad)
        with pytest.raises(InputError, match=said):
            pcreg.crosscheck(source, target, init=bad)
        with pytest.raises(InputError, match=f"truth: .*{said}"):
            pcreg.crosscheck(source, target, truth=bad)
    rounded = np.round(tf.rigid2d(20.0), 3)  # a 3x3 matrix: a 2-D start, its rotation to three decimals
    assert pcreg.icp(source[:, :2], target[:, :2], init=rounded).fitness > 0
    np.save(tmp_path / "s.npy", source)
    np.save(tmp_path / "t.npy", target)
    np.savetxt(tmp_path / "mirror.txt", np.diag([-1.0, 1, 1, 1]))
    assert main(["crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "s.npy"), "--init", str(tmp_path / "mirror.txt")]) == 2
    assert capsys.readouterr().err.startswith(f"pcreg: error: {tmp_path / 'mirror.txt'}: the initial guess: it is a reflection")
    suite = export_suite(tmp_path / "suite", [Case(source, target, np.eye(4), 0.1, name="c", truth=np.eye(4))])
    np.savetxt(suite / "c" / "truth.txt", np.eye(3))
    assert main(["crosscheck", "--suite", str(suite), "--out", str(tmp_path / "o"), "--with", "reference"]) == 2
    assert f"{suite / 'c' / 'truth.txt'} must be a finite 4x4 matrix" in capsys.readouterr().err


def test_an_icp_with_no_pair_or_with_normals_that_fix_nothing_is_refused():
    rng = np.random.default_rng(3)
    target = rng.uniform(0, 1, (300, 3))
    with pytest.raises(pcreg.errors.RegistrationError, match="no source point lies within"):
        pcreg.icp(target + 100, target, pcreg.ICPOptions(max_correspondence_distance=0.5))
    plane = pcreg.ICPOptions(metric="point_to_plane")
    with pytest.raises(InputError, match="300 normal.s. of length 0"):
        pcreg.icp(target + 0.01, target, plane, target_normals=np.zeros_like(target))
    with pytest.raises(InputError, match="span 1 of 3 directions"):
        pcreg.icp(target + 0.01, target, plane, target_normals=np.tile([0.0, 0, 1], (300, 1)))


def test_small_or_integer_clouds_are_cross_checked_as_clouds_and_numpy_scalars_reported_are_read(tmp_path, monkeypatch):
    """An (N, 3) integer cloud, or one of 16 points or fewer, was taken for an image ("image too small to register");
    a py: function's numpy scalars (np.int64 iterations, np.bool_ converged) failed its row, a complex matrix
    lost its imaginary part with a warning, and 1e300 iterations were taken."""
    import sys

    cloud = np.random.default_rng(4).integers(0, 100, (300, 3))
    assert pcreg.crosscheck(cloud, cloud + 1, options=pcreg.ICPOptions(max_correspondence_distance=5.0)).rows["open3d"]["agrees"]
    few = np.random.default_rng(4).random((12, 3))
    report = pcreg.crosscheck(few, few + 0.001, options=pcreg.ICPOptions(max_correspondence_distance=0.5))
    assert report.rows["reference"]["error"] is None
    (tmp_path / "scalars.py").write_text(
        "import numpy as np\n"
        "def numpy_types(source, target, *, init, **kw):\n"
        "    return {'matrix': np.eye(4), 'iterations': np.int64(3), 'fitness': np.float32(0.5), 'converged': np.bool_(True)}\n"
        "def complex_matrix(source, target, *, init, **kw):\n"
        "    return np.eye(4) + 0j\n"
        "def endless(source, target, *, init, **kw):\n"
        "    return {'matrix': np.eye(4), 'iterations': 1e300}\n")
    monkeypatch.setattr(sys, "path", [str(tmp_path), *sys.path])
    rows = pcreg.crosscheck(cloud, cloud + 1, options=pcreg.ICPOptions(max_correspondence_distance=5.0),
                            implementations=["py:scalars:numpy_types", "py:scalars:complex_matrix", "py:scalars:endless"]).rows
    assert rows["py:scalars:numpy_types"]["error"] is None and rows["py:scalars:numpy_types"]["iterations"] == 3
    assert rows["py:scalars:complex_matrix"]["error"] == "returned a matrix that is not numeric"
    assert rows["py:scalars:endless"]["error"] == "iterations must be in 0..100000, got 1e+300"


def test_a_ply_whose_comment_names_end_header_or_whose_header_runs_long_is_read_and_a_wide_line_refused(tmp_path):
    pts = np.random.default_rng(6).normal(size=(40, 3))
    body = "".join(f"{a:.6f} {b:.6f} {c:.6f}\n" for a, b, c in pts)
    props = "element vertex 40\nproperty float x\nproperty float y\nproperty float z\n"
    (tmp_path / "comment.ply").write_text(f"ply\nformat ascii 1.0\ncomment ends at end_header\n{props}end_header\n{body}")
    (tmp_path / "long.ply").write_text("ply\nformat ascii 1.0\n" + "comment x\n" * 20_000 + props + "end_header\n" + body)
    for name in ("comment.ply", "long.ply"):
        np.testing.assert_allclose(load_cloud(tmp_path / name), pts, atol=1e-5)
    # one header line past 1,024 bytes: Open3D's reader overflows its buffer and aborts the whole process
    (tmp_path / "wide.ply").write_text("ply\nformat ascii 1.0\ncomment " + "y " * 600 + "\n" + props + "end_header\n" + body)
    with pytest.raises(InputError, match="a PLY header line of 1208 bytes"):
        load_cloud(tmp_path / "wide.ply")


def test_a_suite_and_its_results_are_not_written_over_without_force_and_an_odd_suite_is_refused(tmp_path, capsys):
    """--export replaced the files of a folder it did not own, and --suite the results of an earlier run; an empty
    suite ran to exit 0, a case named twice ran twice, and a params.json without its distance said "KeyError";
    --model and --levels, which only images take, were ignored for clouds."""
    import json

    from pcreg.cli import main
    from pcreg.implementations.suite import Case, export_suite

    rng = np.random.default_rng(7)
    target = rng.uniform(0, 1, (200, 3))
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    assert main(["crosscheck", "--export", str(mine)]) == 2
    assert "holds files already (use --force" in capsys.readouterr().err and (mine / "notes.txt").read_text() == "mine"
    suite = export_suite(tmp_path / "suite", [Case(target + 0.01, target, np.eye(4), 0.1, name="c")])
    assert main(["crosscheck", "--suite", str(suite), "--with", "reference"]) == 0
    capsys.readouterr()
    assert main(["crosscheck", "--suite", str(suite), "--with", "reference"]) == 2
    assert "results.csv: results of an earlier run (use --force" in capsys.readouterr().err
    assert main(["crosscheck", "--suite", str(suite), "--with", "reference", "--force"]) == 0
    capsys.readouterr()
    index = suite / "index.json"
    for cases, said in (([], "lists no case"), (["c", "c"], "lists the case 'c' twice")):
        index.write_text(json.dumps({"format": 1, "cases": cases}))
        assert main(["crosscheck", "--suite", str(suite), "--out", str(tmp_path / "r"), "--force"]) == 2
        assert said in capsys.readouterr().err
    index.write_text(json.dumps({"format": 1, "cases": ["c"]}))
    (suite / "c" / "params.json").write_text(json.dumps({"max_iterations": 5}))
    assert main(["crosscheck", "--suite", str(suite), "--out", str(tmp_path / "r"), "--force"]) == 2
    assert "params.json: lacks 'max_correspondence_distance'" in capsys.readouterr().err
    np.save(tmp_path / "t.npy", target)
    assert main(["crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "t.npy"), "--model", "similarity"]) == 2
    assert "--model applies to images" in capsys.readouterr().err


def test_a_suite_case_whose_files_do_not_fit_each_other_names_the_file_at_fault(tmp_path, capsys):
    """A 2-D case whose source.npy was replaced by 3-D points was refused as "truth.txt must be a finite 4x4
    matrix" (truth.txt was right); an init.txt of two rows or a reflection as "pinned: init ..." or "init: ...",
    naming no file; a case.json giving another dimension than the clouds' was taken. Each names its file."""
    import shutil

    from pcreg.cli import main
    from pcreg.implementations.suite import Case, export_suite

    target = np.random.default_rng(7).uniform(0, 1, (200, 2))
    for fault, said in ((lambda c: np.save(c / "source.npy", np.arange(30.0).reshape(10, 3)), "target.npy: holds 2-D points, source.npy 3-D"),
                        (lambda c: (c / "init.txt").write_text("1 0 0\n0 1 0\n"), "init.txt must be a finite 3x3 matrix"),
                        (lambda c: (c / "init.txt").write_text("-1 0 0\n0 1 0\n0 0 1\n"), "init.txt: it is a reflection"),
                        (lambda c: (c / "case.json").write_text('{"dimension": 3}'),
                         "source.npy: holds 2-D points, and case.json gives the case's dimension as 3")):
        shutil.rmtree(tmp_path / "suite", ignore_errors=True)
        suite = export_suite(tmp_path / "suite", [Case(target + 0.01, target, np.eye(3), 0.1, name="c")])
        fault(suite / "c")
        assert main(["crosscheck", "--suite", str(suite), "--out", str(tmp_path / "r"), "--force"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"{suite / 'c'}/{said}" in err[0], err


def test_exact_implementations_agree_on_clouds_a_million_metres_from_the_origin():
    """Georeferenced clouds (1e6 m away, a metre across): Open3D's two ICPs part from the reference by their sums'
    rounding alone (2.7e-9 and 3.7e-9 of the matrix), which the fixed 1e-9 called a disagreement."""
    rng = np.random.default_rng(8)
    target = rng.uniform(0, 1, (400, 3)) + 1e6
    T = np.eye(4)
    T[:3, :3] = tf.rigid2d(1.0)
    T[:3, 3] = [0.01, -0.02, 0.0]
    centre = target.mean(axis=0)
    source = (target - centre) @ T[:3, :3] + centre - T[:3, 3]
    rows = pcreg.crosscheck(target, source, implementations=["reference", "open3d", "open3d-tensor"],
                            options=pcreg.ICPOptions(max_correspondence_distance=0.05)).rows
    for name in ("open3d", "open3d-tensor"):
        assert rows[name]["error"] is None and rows[name]["agrees"], (name, rows[name]["matrix_relative_disagreement"])


def test_a_suite_exported_over_an_earlier_one_keeps_nothing_of_its_cases(tmp_path):
    """Exported over an earlier suite (``--export DIR --force``), a case without a truth kept the earlier
    case's truth.txt, which the suite's reader took as this case's truth, and a case the reference refuses
    kept the earlier trace in reference/."""
    from pcreg.implementations.suite import Case, export_suite, load_suite

    rng = np.random.default_rng(7)
    target = rng.uniform(0, 1, (200, 3))
    far = np.eye(4)
    far[:3, 3] = 0.5
    suite = export_suite(tmp_path / "suite", [Case(target + 0.01, target, np.eye(4), 0.1, name="c", truth=far)])
    assert (suite / "c" / "truth.txt").exists() and (suite / "c" / "reference" / "final.txt").exists()
    export_suite(suite, [Case(target + 0.01, target, np.eye(4), 0.1, name="c")])
    assert load_suite(suite)[0].truth is None
    export_suite(suite, [Case(target[:1] + 0.01, target[:1], np.eye(4), 0.1, name="c")])  # one point: refused
    assert "reference_error" in json.loads((suite / "c" / "case.json").read_text())
    assert not (suite / "c" / "reference").exists()


@pytest.mark.parametrize("extra", [[], ["--export", "SUITE"]])
def test_out_without_suite_is_refused_not_ignored(tmp_path, capsys, extra):
    """``--out`` is where ``--suite`` writes: given for two clouds (or with ``--export``) it was taken, nothing was
    written there, and the command exited 0."""
    from pcreg.cli import main

    rng = np.random.default_rng(3)
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    np.save(a, rng.uniform(0, 1, (200, 3)))
    np.save(b, np.load(a) + 0.01)
    given = [str(tmp_path / "suite") if x == "SUITE" else x for x in extra] or [str(a), str(b)]
    assert main(["crosscheck", *given, "--out", str(tmp_path / "res")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"pcreg: error: --out {tmp_path / 'res'}: where --suite writes its "
                                               "results; "), err
    assert not (tmp_path / "res").exists() and not (tmp_path / "suite").exists()


def test_export_and_suite_say_what_they_did_in_words_not_python_values(tmp_path, capsys):
    """``--export`` and ``--suite`` printed their result as Python values (``cases: ['2d-random', ...]``,
    ``skipped: {}``, ``results: {'csv': ...}``); ``--json`` gives the same facts whole."""
    import json

    from pcreg.cli import main

    suite = tmp_path / "suite"
    assert main(["crosscheck", "--export", str(suite), "--suite", str(suite), "--with", "reference",
                 "--scans", str(tmp_path / "none")]) == 0
    captured = capsys.readouterr()
    said = captured.out.splitlines()
    assert said, captured.err
    assert said[0].startswith(f"exported 14 case(s) to {suite}: 2d-random, 2d-edges, ")
    assert said[1].startswith("13 of 14 row(s) agree with the reference ICP; results: ")  # 3d-collinear is refused
    assert f"{suite / 'results.md'}" in said[1]
    assert said[2].startswith("skipped lidar: the LiDAR pair is not at ") and len(said) == 3
    assert not any(c in line for line in said[:2] for c in "[]{}'")
    assert "lidar" in (suite / "results.md").read_text()  # the suite's results name the case it lacks, as the terminal
    assert main(["crosscheck", "--suite", str(suite), "--with", "reference", "--json", "--force"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert (out["agreeing"], out["rows"], out["skipped"]) == (13, 14, {})
