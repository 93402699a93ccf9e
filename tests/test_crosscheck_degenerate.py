"""Cross-checks on clouds that leave the rigid transform free, and on hostile inputs: a pose that cannot be
trusted is marked in every row and in the table, never listed as a plain converged result."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import pcreg
from pcreg import transforms as tf
from pcreg.commands.crosscheck import format_table
from pcreg.implementations.crosscheck import compare_matrices

PAIR = ("reference", "open3d", "open3d-tensor")


def _line3(n=300):
    return np.column_stack([np.linspace(-10, 10, n), np.zeros(n), np.zeros(n)])


def _shifted(points, *shift):
    T = np.eye(points.shape[1] + 1)
    T[:-1, -1] = shift
    return tf.apply(T, points)


@pytest.mark.parametrize("cloud, said", [(_line3(), "collinear"), (np.ones((20, 3)), "coincident")])
def test_a_3d_line_or_one_repeated_point_marks_every_pose_unconstrained(cloud, said):
    # The reference refuses (the rotation about the line, or about the point, is free); the others return
    # a pose, which a row must not list as a plain converged result.
    report = pcreg.crosscheck(_shifted(cloud, 0.2, 0.1, 0.0), cloud, implementations=PAIR,
                              options=pcreg.ICPOptions(max_correspondence_distance=2.0))
    reason = report.settings["unconstrained"]
    assert reason.startswith("source: ") and said in reason
    assert said in report.rows["reference"]["error"] and report.rows["reference"]["status"] == "failed"
    for name in PAIR[1:]:
        row = report.rows[name]
        assert row["matrix"] is not None, row["error"]
        assert row["status"] == "unconstrained" and row["unconstrained"] == reason and not row["agrees"]
        assert row["info"]["unconstrained"] == reason
    table = format_table(report.to_dict())
    assert table.count("unconstrained, not trusted: " + reason) == len(PAIR) - 1
    assert f"unconstrained: {reason}; no row's pose can be trusted" in table
    assert json.loads(json.dumps(report.to_dict()))["implementations"]["open3d"]["status"] == "unconstrained"


def _far_line():
    """100 points of a 3-D line 1 unit long, 1e6 from the origin: float64's rounding of its coordinates and of their
    mean made it read as a thin 3-D cloud (its second singular value 1.4e-9 of its first, above the 1e-9 allowed)."""
    d = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)
    return 1e6 + np.linspace(0, 1, 100)[:, None] * d


def test_a_line_far_from_the_origin_is_refused_and_marked_as_at_the_origin():
    """The far line: open3d returned a half turn about it (fitness 1, converged) and the reference a shift, neither
    refused; the cross-check marked no row unconstrained. A plane 1e8 away was registered by an affine mirror."""
    from pcreg.errors import RegistrationError

    line = _far_line()
    for backend in ("reference", "open3d"):
        with pytest.raises(RegistrationError, match="the points are collinear"):
            pcreg.icp(line, line + [0.02, 0.01, -0.01], pcreg.ICPOptions(backend=backend, max_correspondence_distance=1.0))
    report = pcreg.crosscheck(line + [0.02, 0.01, -0.01], line, implementations=PAIR,
                              options=pcreg.ICPOptions(max_correspondence_distance=1.0))
    assert "collinear" in report.settings["unconstrained"]
    assert all(report.rows[name]["status"] == "unconstrained" for name in PAIR[1:])
    rng = np.random.default_rng(9)
    uv = rng.uniform(0, 1, (200, 2))
    e2 = np.cross(_far_line()[1] - _far_line()[0], [0, 0, 1.0])
    plane = 1e8 + uv[:, :1] * np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0) + uv[:, 1:] * e2 / np.linalg.norm(e2)
    with pytest.raises(RegistrationError, match="the points are coplanar: they cannot determine an affine"):
        pcreg.icp(plane, plane + [0.01, 0.02, 0], pcreg.ICPOptions(model="affine", max_correspondence_distance=0.5))
    cloud = 1e6 + rng.uniform(0, 1, (300, 3))  # a 3-D cloud as far: registered as before
    r = pcreg.icp(cloud, cloud + [0.02, 0.01, -0.01], pcreg.ICPOptions(max_correspondence_distance=1.0))
    assert r.fitness == 1.0 and np.abs(tf.apply(r.matrix, cloud) - (cloud + [0.02, 0.01, -0.01])).max() < 1e-6


def test_the_reason_is_the_reference_icps_own():
    from pcreg.errors import RegistrationError
    from pcreg.implementations.crosscheck import unconstrained

    with pytest.raises(RegistrationError) as refused:
        pcreg.icp(_line3(), _line3(), pcreg.ICPOptions(max_correspondence_distance=1.0))
    assert unconstrained(_line3(), _line3()) == f"source: {refused.value}"
    assert unconstrained(np.random.default_rng(0).uniform(0, 1, (50, 3)), _line3()).startswith("target: the points "
                                                                                                 "are collinear")


@pytest.mark.parametrize("cloud", [
    np.column_stack([np.random.default_rng(1).uniform(-10, 10, (400, 2)), np.zeros(400)]),  # a 3-D plane
    np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]),  # three collinear points in 2-D: the rotation is fixed
    np.array([[0.0, 0.0], [1.0, 0.0]]),  # two points in 2-D
])
def test_a_plane_in_3d_or_a_line_in_2d_constrains_the_pose_and_is_not_marked(cloud):
    report = pcreg.crosscheck(_shifted(cloud, *([0.01] + [0.0] * (cloud.shape[1] - 1))), cloud, implementations=PAIR,
                              options=pcreg.ICPOptions(max_correspondence_distance=0.5))
    assert report.settings["unconstrained"] is None
    for name, row in report.rows.items():
        assert row["status"] == "ok" and row["unconstrained"] is None and row["agrees"], (name, row)


@pytest.mark.parametrize("dim", [2, 3])
def test_identical_clouds_give_the_identity_trusted(dim):
    cloud = np.random.default_rng(dim).uniform(0, 10, (400, dim))
    report = pcreg.crosscheck(cloud, cloud.copy(), implementations=PAIR)
    for name, row in report.rows.items():
        assert row["status"] == "ok" and row["agrees"] and row["converged"], name
        np.testing.assert_allclose(row["matrix"], np.eye(dim + 1), atol=1e-12, err_msg=name)
        assert row["fitness"] == 1.0 and row["inlier_rmse"] < 1e-12


@pytest.mark.parametrize("angle", [0.001, 1.0, 10.0, 45.0, 90.0, 135.0, 179.0])
def test_a_2d_rotation_disagreement_is_the_angle_between_the_rotations(angle):
    # It was sqrt(2) times the angle for small angles, and 180 degrees from 90 degrees on.
    src = np.random.default_rng(0).uniform(0, 10, (20, 2))
    assert compare_matrices(np.eye(3), tf.rigid2d(angle), src)["rotation_disagreement_deg"] == pytest.approx(angle)


def test_a_square_turned_a_quarter_fits_itself_and_the_truth_says_how_far_off():
    # A square maps onto itself turned 90 degrees: every ICP stays at the identity, a perfect fit, and agrees.
    # Nothing in the clouds tells the symmetry apart; a given truth does, by the right angle.
    g = np.linspace(-1, 1, 21)
    square = np.unique(np.vstack([np.c_[g, -np.ones(21)], np.c_[g, np.ones(21)], np.c_[-np.ones(21), g],
                                  np.c_[np.ones(21), g]]), axis=0)
    T = tf.rigid2d(90.0)
    report = pcreg.crosscheck(tf.apply(T, square), square, implementations=PAIR, truth=T,
                              options=pcreg.ICPOptions(max_correspondence_distance=0.5))
    for name, row in report.rows.items():
        assert row["agrees"], name
        assert row["truth_rotation_deg"] == pytest.approx(90.0), name


@pytest.mark.parametrize("shape", [(1000, 4), (5, 4), (10, 1)])
def test_an_array_of_points_of_another_dimension_is_refused_as_points_not_as_a_small_image(shape):
    from pcreg.errors import InputError

    a = np.random.default_rng(0).uniform(0, 1, shape)
    good = np.random.default_rng(1).uniform(0, 1, (50, 3))
    with pytest.raises(InputError, match=rf"reference: expected an \(N, 2\) or \(N, 3\) array of points .*got shape "
                                         rf"\({shape[0]}, {shape[1]}\)"):
        pcreg.crosscheck(a, good)
    with pytest.raises(InputError, match="moving: expected an"):
        pcreg.crosscheck(good, a)


def test_the_command_on_a_3d_line_exits_3_and_its_table_and_json_mark_the_poses(tmp_path, capsys):
    from pcreg.cli import main

    np.save(tmp_path / "t.npy", _line3())
    np.save(tmp_path / "s.npy", _shifted(_line3(), 0.2, 0.1, 0.0))
    args = ["crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "s.npy"), "--max-distance", "2",
            "--with", "reference,open3d"]
    assert main(args) == 3
    out, err = capsys.readouterr()
    s, t = tmp_path / "s.npy", tmp_path / "t.npy"
    # before: "source: the points ...", and the refusal did not say which of the two clouds is a line
    assert f"unconstrained, not trusted: {s}: the points are collinear" in out
    assert err == f"pcreg: registration refused: the reference ICP failed to register {s} onto {t}: {s}: the points are collinear: they cannot determine a rigid transform\n"
    assert main([*args, "--json"]) == 3
    row = json.loads(capsys.readouterr().out)["implementations"]["open3d"]
    assert row["status"] == "unconstrained" and row["unconstrained"].startswith(f"{s}: the points are collinear")
    assert not row["agrees"]
    np.save(s, np.random.default_rng(0).uniform(0, 1, (50, 3)))  # the target alone a line: named
    assert main(args) == 3
    assert f"onto {t}: {t}: the points are collinear" in capsys.readouterr().err


def _turned_at_step_one(trace, degrees):
    """``trace`` with the pose after its first step turned by ``degrees`` about z through the origin: another step
    from the same correspondences."""
    from dataclasses import replace

    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_rotvec([0.0, 0.0, np.radians(degrees)]).as_matrix()
    return (trace[0], replace(trace[1], matrix=turn @ trace[1].matrix), *trace[2:])


def test_a_step_that_parts_where_the_pairs_leave_the_rotation_free_says_so():
    """Two rows that part at a step whose pairs leave the rotation undetermined (from far away every source point is
    nearest to one target corner: any turn fits those pairs as well) are told apart from a step that differs on pairs
    that fix the rotation: the cause says the pairs leave the rotation undetermined, and why, only in the first."""
    from pcreg.implementations.base import Pinned
    from pcreg.implementations.builtin import Reference
    from pcreg.implementations.crosscheck import trace_divergence

    grid = np.stack(np.meshgrid(*[np.arange(5.0)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    for shift, free in ((60.0, "their target points are coincident"), (0.2, None)):
        target = _shifted(grid, shift, shift, shift)
        pinned = Pinned(grid, target, np.eye(4), 1000.0, 30)
        ref = Reference().run(pinned, trace=True).trace
        other = _turned_at_step_one(ref, 5.0)
        cause = trace_divergence(ref, other, source=grid, target=target)["cause"]
        assert cause.startswith("different step from the same correspondences")
        if free is None:
            assert "undetermined" not in cause
        else:
            assert f"which leave the rotation undetermined ({free}" in cause
        assert "undetermined" not in trace_divergence(ref, other)["cause"]  # without the clouds: not known


def test_a_crosscheck_of_no_iterations_is_refused_naming_the_option_as_it_is_spelled():
    # pcreg.icp takes max_iteration=0 (the initial pose, as Open3D); a cross-check of it compares nothing
    cloud = np.random.default_rng(0).random((50, 2))
    assert np.array_equal(pcreg.icp(cloud, cloud + 0.01, pcreg.ICPOptions(max_iteration=0)).matrix, np.eye(3))
    with pytest.raises(pcreg.InputError, match="options.max_iteration must be 1 or more in a cross-check"):
        pcreg.crosscheck(cloud, cloud + 0.01, options=pcreg.ICPOptions(max_iteration=0))
