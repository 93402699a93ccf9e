"""A cross-check's verdicts: the same poses of the same clouds agree, or not, in whatever unit the clouds are
given and wherever they lie; a pose is judged by all it does to the cloud."""

import importlib.util

import numpy as np
import pytest

from pcreg.implementations.crosscheck import crosscheck_implementations
from pcreg.registration.icp_options import ICPOptions


def test_an_icp_that_never_moves_disagrees_in_every_unit(on_path):
    """Clouds 1.7 units across, moved by 0.3% of that: an implementation that returns its initial guess disagrees.
    The same clouds in units 1e4 times larger (1.7e-4 across: micrometres given in metres) agreed at the
    fixed point (relative matrix difference 4e-7, the translation's error in the clouds' units), and
    1e7 times larger at the step tolerance (4e-10)."""
    (on_path / "lazy.py").write_text(
        "def still(source, target, *, init, **kw):\n"
        "    return init\n"
        "still.comparability = 'fixed-point'\n"
        "def still_step(source, target, *, init, **kw):\n"
        "    return init\n")
    tgt = np.random.default_rng(1).uniform(-0.5, 0.5, (500, 3))
    shift = np.array([0.004, -0.003, 0.002])
    seen = {}
    for unit in (1.0, 1e-4, 1e-7):
        r = crosscheck_implementations((tgt - shift) * unit, tgt * unit,
                                       implementations=["py:lazy:still", "py:lazy:still_step"])
        for name in ("py:lazy:still", "py:lazy:still_step"):
            row = r.rows[name]
            assert row["status"] == "ok" and row["agrees"] is False, (unit, name, row["matrix_relative_disagreement"])
            seen.setdefault(name, []).append(row["matrix_relative_disagreement"])
        assert r.rows["reference"]["agrees"] is True
    for name, values in seen.items():  # the same poses of the same clouds differ as much in any unit
        np.testing.assert_allclose(values, values[0], rtol=1e-6, err_msg=name)


def test_a_step_implementation_far_from_the_origin_agrees_whatever_the_clouds_extent():
    """Clouds 1e6 from the origin and 17 units across: Open3D's tensor ICP differs from the reference by a few
    float64 roundings of the coordinates (2e-9 in the translation), and was judged to disagree in the step
    tolerance, which allows 100 roundings of the largest coordinate over the extent (1.3e-9) but was
    compared with the translation in the clouds' units."""
    t = np.random.default_rng(0).uniform(size=(500, 3))
    r = crosscheck_implementations(t * 10 + 1e6 + 0.01, t * 10 + 1e6, implementations=["open3d", "open3d-tensor"])
    for name in ("open3d", "open3d-tensor"):
        row = r.rows[name]
        assert row["error"] is None and row["agrees"] is True, (name, row["matrix_relative_disagreement"])


@pytest.mark.parametrize("offset", [1e5, 1e6])
def test_rows_agree_on_a_translation_of_clouds_far_from_the_origin_and_a_few_units_across(offset):
    """A translation of 0.02 of 300 points 2 units across, 1e5 or 1e6 from the origin: Open3D's rows (and
    small_gicp's at the fixed point) differed from the reference by 1e-8 .. 3.6e-6 in the relative matrix, against a
    tolerance of 100 roundings of the coordinates over the extent (6e-9), and were said to disagree, "a different
    step from the same correspondences", though each put the points within 4e-10 of the truth. A rotation solved
    from such coordinates is rounded by about eps x far; the matrices' translations carry that by the distance
    again. The poses are compared about the source's centroid, where the translations are where they put it."""
    rng = np.random.default_rng(3)
    tgt = rng.uniform(-1, 1, (300, 3)) + offset
    r = crosscheck_implementations(tgt - 0.02, tgt, implementations=["open3d", "open3d-tensor", "small_gicp"],
                                   options=ICPOptions(max_correspondence_distance=0.2))
    for name in ("open3d", "open3d-tensor", "small_gicp"):
        row = r.rows[name]
        assert row["error"] is None and row["agrees"] is True, (name, row["matrix_relative_disagreement"])
        assert row["centroid_disagreement"] < 1e-8 and row["pose_relative_disagreement"] < 1e-9, row


def test_a_translation_off_by_a_thousandth_of_the_extent_far_from_the_origin_disagrees():
    """The poses compared about the cloud: a step 0.1% of the extent off, 1e6 from the origin, is no rounding."""
    from pcreg.implementations.compare import _agrees, compare_matrices, step_tolerance

    src = np.random.default_rng(0).uniform(-0.5, 0.5, (300, 3)) + 1e6
    A, B = np.eye(4), np.eye(4)
    B[0, 3] = 1e-3 * np.sqrt(3)
    cmp = compare_matrices(A, B, src, length=np.sqrt(3))
    step = step_tolerance(src, np.sqrt(3))
    assert not _agrees("step", cmp, np.sqrt(3), step) and not _agrees("fixed-point", cmp, np.sqrt(3), step)


def test_an_objective_row_that_shrinks_the_cloud_disagrees():
    """pycpd's "rigid" model fits a scale: with a cluster of extra target points about the centre it shrank the
    cloud by 2% (points 0.37 from where the reference puts them, 1% of the diagonal), with its rotation 0.13 degrees
    and its centroid 0.085 from the reference's, and its row agreed: the objective test saw no scale."""
    pytest.importorskip("pycpd")
    rng = np.random.default_rng(0)
    src = rng.uniform(-10, 10, (400, 3))
    tgt = np.vstack([src, rng.normal(scale=4.0, size=(300, 3))])
    r = crosscheck_implementations(src, tgt, implementations=["pycpd"])
    row = r.rows["pycpd"]
    assert row["status"] == "ok" and abs(row["info"]["scale"] - 1) > 0.01, row["info"]
    assert row["rotation_disagreement_deg"] <= 0.5 and row["centroid_disagreement"] <= 0.005 * r.settings["target_diagonal"]
    assert row["agrees"] is False
    assert row["scale_disagreement"] == pytest.approx(abs(row["info"]["scale"] - 1), rel=1e-9)
    assert r.rows["reference"]["scale_disagreement"] == 0.0


@pytest.mark.parametrize("unit", [1.0, 1e-6])
def test_the_reference_runs_to_convergence_in_any_unit(unit):
    """The built-in 2-D partial-overlap case needs 137 iterations to converge. Given in units a million times larger
    (clouds 2.4e-5 across), the reference "to convergence" stopped after 128 (an absolute 1e-12 on the inlier
    RMSE's change, met before the pairs settled), and KISS-ICP's fixed point, the same as at unit 1, disagreed
    with it (relative 0.003)."""
    pytest.importorskip("kiss_icp")
    from pcreg import ICPOptions
    from pcreg.implementations.suite import builtin_cases

    c = next(c for c in builtin_cases()[0] if c.name == "2d-partial")
    r = crosscheck_implementations(c.source * unit, c.target * unit, implementations=["kiss-icp"],
                                   options=ICPOptions(max_correspondence_distance=c.max_correspondence_distance * unit))
    assert r.reference_at_convergence["iterations"] == 137
    assert r.rows["kiss-icp"]["agrees"] is True, r.rows["kiss-icp"]["matrix_relative_disagreement"]


@pytest.mark.data
@pytest.mark.parametrize("offset", [0.0, 1e5])
def test_small_gicp_reaches_the_fixed_point_far_from_the_origin(shared_data, offset):
    """The LiDAR pair moved 1e5 m from the origin (as a pair in UTM coordinates lies): small_gicp's Gauss-Newton
    steps about the origin stopped 0.027 degrees and 4 mm from the fixed point the reference and KISS-ICP reach
    (relative 0.054), and its row disagreed; near the origin it agreed to 2e-11."""
    pytest.importorskip("small_gicp")
    from pcreg import ICPOptions
    from pcreg.cloud_reader import load_cloud
    from pcreg.registration.api import voxel_downsample

    scans = shared_data / "scans"
    source, target = (voxel_downsample(load_cloud(scans / f"{n}.ply"), 0.5) for n in ("source", "target"))
    r = crosscheck_implementations(source + offset, target + offset, implementations=["small_gicp"],
                                   options=ICPOptions(max_correspondence_distance=1.0))
    row = r.rows["small_gicp"]
    assert row["agrees"] is True, (row["matrix_relative_disagreement"], row["rotation_disagreement_deg"])


@pytest.mark.parametrize("unit", [1.0, 1e-9, 1e-12, 1e6])
def test_small_gicp_agrees_in_units_a_trillion_times_smaller(unit):
    """small_gicp stops when a step's translation is under an absolute criterion, and solves with absolute damping:
    with the criterion 1e-12 of the target's extent floored at 1, its rows on clouds 1e-12 across stopped at
    iteration 0, 2.9 degrees from the reference, and read "no" (with the floor taken off, 4 degrees off at
    iteration 4: the rotation's part of its system is the extent squared). The clouds are given to it in units of
    the target's extent."""
    pytest.importorskip("small_gicp")
    from pcreg import ICPOptions
    from pcreg.implementations.suite import builtin_cases

    c = next(c for c in builtin_cases()[0] if c.name == "3d-random")
    kinds = ["small_gicp", "small_gicp-plane", "small_gicp-gicp"]
    r = crosscheck_implementations(c.source * unit, c.target * unit, implementations=kinds,
                                   options=ICPOptions(max_correspondence_distance=c.max_correspondence_distance * unit))
    for kind in kinds:
        row = r.rows[kind]
        assert row["agrees"] is True and row["iterations"] > 1, (kind, row["iterations"], row["rotation_disagreement_deg"])


@pytest.mark.parametrize("unit, offset", [(1.0, 0.0), (1e6, 0.0), (1.0, 1e6), (0.01, 1e6), (0.001, 1e5)])
def test_kiss_icp_converges_in_any_unit_and_far_from_the_origin(unit, offset):
    """KISS-ICP's stopping rule is a step's norm (translation and rotation vector) under a criterion: an absolute
    1e-12 was never met once the translation's roundings were larger (clouds in units a million times smaller,
    or 1e6 from the origin), and its row ran all 200 iterations and said it had not converged, at the fixed
    point the reference reaches in 4 (its own 5 near the origin). Clouds far from the origin for their size (0.2
    across, 1e6 away) did so still with that criterion relative to their coordinates: its Gauss-Newton steps are
    solved about the origin (two bunny scans 0.15 across, 1e6 away, ended 114 degrees off). Its row runs on the
    clouds about the target's centroid, as small_gicp's."""
    pytest.importorskip("kiss_icp")
    from pcreg import ICPOptions
    from pcreg.implementations.suite import builtin_cases

    c = next(c for c in builtin_cases()[0] if c.name == "3d-random")
    r = crosscheck_implementations(c.source * unit + offset, c.target * unit + offset, implementations=["kiss-icp"],
                                   options=ICPOptions(max_correspondence_distance=c.max_correspondence_distance * unit))
    row = r.rows["kiss-icp"]
    assert row["agrees"] is True and row["converged"] is True and row["iterations"] <= 10, row["iterations"]


def test_the_table_shows_how_far_the_poses_put_the_cloud_wherever_it_lies():
    """Clouds 5e6 from the origin, 2 units across, turned 3 degrees: Open3D's row agrees with the reference step
    for step. The matrices' translations still differ by 5e-4 (their rotations' 3e-9 degrees times 5e6), which the
    table showed as `transl`; where the two poses put the source's centroid differs by 2e-9 (measured)."""
    from scipy.spatial.transform import Rotation

    from pcreg.commands.crosscheck import format_table
    from pcreg.registration.icp_options import ICPOptions

    tgt = np.random.default_rng(0).uniform(-1, 1, (500, 3)) + 5e6
    c = tgt.mean(axis=0)
    src = (tgt - c) @ Rotation.from_euler("z", 3, degrees=True).as_matrix().T + c + 0.01
    r = crosscheck_implementations(src, tgt, implementations=["reference", "open3d"],
                                   options=ICPOptions(max_correspondence_distance=0.5))
    row = r.rows["open3d"]
    assert row["agrees"] and row["translation_disagreement"] > 1e-5, row  # the matrices' translations differ
    head, ref_line, o3d_line = format_table(r.to_dict()).splitlines()[:3]
    end = head.index("centroid") + len("centroid")  # the columns are right-aligned, 9 wide
    shown = float(o3d_line[end - 9:end])
    assert shown == pytest.approx(row["centroid_disagreement"], rel=1e-2) and shown < 1e-6  # measured 1.9e-9


def test_a_mixture_that_ends_wider_than_the_gate_says_so_on_its_row():
    """A uniform square of 500 points shifted by 1% of its side: probreg's CPD stops with its mixture's sigma
    at 0.26, 19x the gate (the same with 10x the iterations and no tolerance), 0.7 degrees from the reference, and
    its row read only "no". Its row now says how wide the mixture ended; a row that agrees says nothing of it."""
    pytest.importorskip("probreg")
    from pcreg.commands.crosscheck import format_table

    rng = np.random.default_rng(0)
    a = np.c_[rng.random((500, 2)), np.zeros(500)]
    r = crosscheck_implementations(a + [0.01, 0.01, 0.0], a, implementations=["reference", "probreg-cpd"])
    row, gate = r.rows["probreg-cpd"], r.settings["max_correspondence_distance"]
    assert row["agrees"] is False and np.sqrt(row["info"]["sigma2"]) > 5 * gate, (row["info"], gate)
    lines = format_table(r.to_dict()).splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("probreg-cpd"))
    sigma = np.sqrt(row["info"]["sigma2"])
    assert lines[at + 1].split()[:5] == ["its", "mixture", "ended", "wide:", "sigma"]
    assert f"{sigma:.3g}" in lines[at + 1] and f"{sigma / gate:.3g}x the gate" in lines[at + 1]
    assert sum("mixture ended wide" in line for line in lines) == 1  # the reference's row: none


def test_a_step_row_that_stopped_before_converging_says_so():
    """A turn of 60 degrees that the step rows do not finish in their iterations: the reference's row read rmse 0.06
    beside fixed-point rows at 1e-16 that "agree" (compared with the reference run on to convergence, which the
    table said only in its footer). The step rows say they stopped; the reference's says what it reaches."""
    from scipy.spatial.transform import Rotation

    from pcreg.commands.crosscheck import format_table
    from pcreg.registration.icp_options import ICPOptions

    rng = np.random.default_rng(7)
    tgt = rng.normal(size=(1500, 3)) * [2.0, 1.0, 0.5]
    src = (tgt - [2.0, 1.0, 0.5]) @ Rotation.from_euler("z", -60, degrees=True).as_matrix().T + [2.0, 1.0, 0.5]
    names = ["reference", "open3d"] + (["small_gicp"] if importlib.util.find_spec("small_gicp") else [])
    r = crosscheck_implementations(src, tgt, implementations=names,
                                   options=ICPOptions(max_correspondence_distance=5.0, max_iteration=4))
    assert r.rows["reference"]["converged"] is False
    lines = format_table(r.to_dict()).splitlines()
    for name in ("reference", "open3d"):
        at = next(i for i, line in enumerate(lines) if line.startswith(name))
        assert lines[at + 1].split()[:8] == ["stopped", "at", "its", "4", "iterations", "before", "its", "stopping"]
    if "small_gicp" in names:
        conv = r.to_dict()["reference_at_convergence"]
        assert f"run on, the reference converges in {conv['iterations']} (rmse" in "\n".join(lines)
    r = crosscheck_implementations(src, tgt, implementations=["reference", "open3d"],
                                   options=ICPOptions(max_correspondence_distance=5.0, max_iteration=200))
    assert r.rows["reference"]["converged"] and "stopped at its" not in format_table(r.to_dict())


@pytest.mark.parametrize("conv, said", [
    (None, ""),
    ({"error": "run-on failed"}, "; run on, the reference failed (run-on failed)"),
    ({"iterations": 200, "converged": False, "inlier_rmse": 0.5}, "; run on, the reference had not converged in 200 (rmse 0.5)"),
    ({"iterations": 46, "converged": True, "inlier_rmse": None}, "; run on, the reference converges in 46, which"),
])
def test_what_the_reference_reached_run_on_is_said_as_it_came(conv, said):
    """The reference run on to convergence may fail, stop at its own limit or give no rmse: the stopped row said
    "converges in" regardless, and a failed run-on ended the table in a KeyError."""
    from pcreg.commands.crosscheck import _run_on

    assert _run_on(conv).startswith(said)


def test_rows_whose_names_are_cut_are_told_apart_and_named_in_full_below():
    """Two `cmd:` implementations whose commands differ after their 21st character: both rows read
    `cmd:"/tmp/p1/work/icp...`, one agreeing and one not, and only their order told which was which."""
    from pcreg.commands.crosscheck import format_table

    a = np.random.default_rng(1).uniform(-1, 1, (300, 3))
    out = crosscheck_implementations(a + 0.01, a, implementations=["reference", "open3d"]).to_dict()
    rows = out["implementations"]
    one, other = 'cmd:"/opt/tools/icp_min {source} {target}"', 'cmd:"/opt/tools/icp_min {source} {target} --wrong"'
    rows[one], rows[other] = rows.pop("open3d"), dict(rows["reference"], agrees=False)
    lines = format_table(out).splitlines()
    labels = [line[:24].rstrip() for line in lines[1:4]]
    assert labels == ["reference", 'cmd:"/opt/tools/i... [1]', 'cmd:"/opt/tools/i... [2]'], labels
    assert lines[-2:] == [f"[1] {one}", f"[2] {other}"], lines[-2:]


def test_clouds_far_from_the_origin_for_their_size_agree_no_further_apart_than_objective_rows(on_path):
    """800 points 1e-7 across, 1e7 from the origin, turned 31 degrees about their centroid: the step allowance for
    coordinates far from the origin came to 0.65 relative, and KISS-ICP's row, which never moved (it solved its steps
    about the origin then), read "agrees" 31.5 degrees from the reference's. Such an allowance lets a row agree no
    further apart than an objective row may: here a row that returns its initial guess."""
    from scipy.spatial.transform import Rotation

    from pcreg.implementations.compare import OBJECTIVE_ROTATION_DEG, _agrees

    rng = np.random.default_rng(2)
    source = rng.uniform(-1, 1, (800, 3)) * 1e-7 + 1e7
    centre = source.mean(axis=0)
    target = (source - centre) @ Rotation.from_rotvec([0.2, -0.3, 0.4]).as_matrix().T + centre + 2e-9
    (on_path / "idle.py").write_text("def still(source, target, *, init, **kw):\n    return init\n"
                                     "still.comparability = 'fixed-point'\n")
    rows = crosscheck_implementations(source, target, implementations=["reference", "py:idle:still"],
                                      options=ICPOptions(max_correspondence_distance=3e-7)).rows
    assert rows["py:idle:still"]["rotation_disagreement_deg"] > 10 and rows["py:idle:still"]["agrees"] is False
    close = {"pose_relative_disagreement": 0.3, "rotation_disagreement_deg": OBJECTIVE_ROTATION_DEG / 2,
             "centroid_disagreement": 0.0, "scale_disagreement": 0.0}
    assert _agrees("step", close, 1.0, step=0.65) and not _agrees("step", {**close, "rotation_disagreement_deg": 31.5},
                                                                   1.0, step=0.65)


def test_a_row_that_fits_better_than_the_reference_says_so(on_path):
    """probreg's FilterReg on a bunny turned 30 degrees among outliers fits it to an RMSE of 0.0019, where the
    reference ICP stops in a local minimum at 0.011, 49 degrees away: the row read "no" and nothing else, as if it
    were the wrong one. Here an L of points turned 120 degrees: the reference stops half a turn off; a row that
    returns the true turn says it fits better (ICP's own measure, the RMS distance capped at the gate), and one that
    never moves, worse, says nothing of it."""
    from scipy.spatial.transform import Rotation

    from pcreg.commands.crosscheck import format_table

    rng = np.random.default_rng(0)  # ICP ends half a turn off from seeds 0 to 5 alike (capped RMS 0.030-0.037)
    a = np.c_[rng.random((300, 2)) * [1.0, 0.3], np.zeros(300)]
    a = np.r_[a, np.c_[rng.random((60, 2)) * 0.2 + [0.8, 0.3], np.zeros(60)]]
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_euler("z", 120, degrees=True).as_matrix()
    (on_path / "known.py").write_text(
        "import numpy as np\n"
        f"TURN = np.array({turn.tolist()})\n"
        "def truth(source, target, *, init, **kw):\n"
        "    return TURN\n"
        "truth.comparability = 'objective'\n"
        "def still(source, target, *, init, **kw):\n"
        "    return init\n"
        "still.comparability = 'objective'\n")
    r = crosscheck_implementations(a, a @ turn[:3, :3].T, implementations=["py:known:truth", "py:known:still"],
                                   options=ICPOptions(max_correspondence_distance=0.3))
    truth, still = r.rows["py:known:truth"], r.rows["py:known:still"]
    assert truth["agrees"] is False and truth["rotation_disagreement_deg"] > 90  # the reference is the one off
    better = truth["better_fit"]
    assert better["capped_rms"] < 1e-9 and better["compared_with_capped_rms"] > 0.01, better
    assert still["agrees"] is False and still["better_fit"] is None and r.rows["reference"]["better_fit"] is None
    lines = format_table(r.to_dict()).splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("py:known:truth"))
    assert "fits the clouds better than the reference run to convergence" in lines[at + 1]
    assert sum("fits the clouds better" in line for line in lines) == 1


def test_a_row_that_scales_fits_better_far_from_the_origin_too_and_the_suite_says_so(on_path, tmp_path):
    """A row that fits a scale (pycpd's rigid model does, 1.001-1.14 measured) was judged at its nearest rigid pose
    with the scale dropped about the origin, which moves the cloud (1 - s) times its distance from it: 1e3 away, the
    row that fits better was said to fit no better. And ``--suite`` left ``better_fit`` out of its rows and its
    report."""
    from scipy.spatial.transform import Rotation

    from pcreg.implementations.compare import _better_fit
    from pcreg.implementations.suite import Case, run_suite, write_results
    from pcreg.registration.transforms import about_point

    rng = np.random.default_rng(0)
    a = np.c_[rng.random((300, 2)) * [1.0, 0.3], np.zeros(300)]
    a = np.r_[a, np.c_[rng.random((60, 2)) * 0.2 + [0.8, 0.3], np.zeros(60)]]
    turn = Rotation.from_euler("z", 120, degrees=True).as_matrix()

    class Pinned:
        max_correspondence_distance = 0.3

    class Pose:
        def __init__(self, matrix):
            self.matrix = matrix

    for offset in (0.0, 1e3):
        source, target = a + offset, a @ turn.T + offset
        truth = np.eye(4)
        truth[:3, :3], truth[:3, 3] = turn, offset - turn @ np.full(3, offset)
        scaled = about_point(np.diag([1.002, 1.002, 1.002, 1.0]), target.mean(axis=0)) @ truth
        Pinned.target = target
        better = _better_fit(Pose(scaled), Pose(np.eye(4)), "reference", source, Pinned)
        assert better is not None and better["capped_rms"] < 0.01, (offset, better)
    (on_path / "known2.py").write_text(
        "import numpy as np\n"
        f"TURN = np.array({[[*row, 0.0] for row in turn[:2, :2].tolist()] + [[0.0, 0.0, 1.0]]})\n"
        "def truth(source, target, *, init, **kw):\n"
        "    return TURN\n"
        "truth.comparability = 'objective'\n")
    flat = a[:, :2]
    rows = run_suite([Case(flat, flat @ turn[:2, :2].T, np.eye(3), 0.3, 30, 1e-6, 1e-6, name="L")], ["py:known2:truth"])
    row = next(r for r in rows if r["implementation"] == "py:known2:truth")
    assert row["agrees"] is False and row["better_fit"]["capped_rms"] < 1e-9
    write_results(tmp_path / "suite", rows)
    report = (tmp_path / "suite" / "results.md").read_text()
    assert "Fits the clouds better than the reference" in report and "- L / py:known2:truth: RMS distance" in report


def _surface(seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """A smooth surface a unit across, and the same turned 20 degrees about z and shifted."""
    rng = np.random.default_rng(seed)
    u, v = rng.random((2, 2000))
    a = np.c_[u, v, 0.3 * np.sin(3 * u) * np.cos(2 * v)]
    t = 0.35
    R = np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])
    return a, (a - a.mean(0)) @ R.T + a.mean(0) + [0.05, 0.02, 0]


def test_a_gate_that_takes_every_pair_leaves_the_reference_run_to_convergence():
    """A gate of 1e9 on clouds a unit across (every pair): "to convergence" stopped on the inlier RMSE's change
    below 1e-12 of the gate, 1e-3, after 9 iterations at RMSE 0.024, and small_gicp, at the pose the reference's own
    row reached, was said to disagree and to fit better than ICP's best."""
    pytest.importorskip("small_gicp")
    a, b = _surface()
    r = crosscheck_implementations(a, b, implementations=["small_gicp"],
                                   options=ICPOptions(max_correspondence_distance=1e9, max_iteration=200))
    assert r.reference_at_convergence["inlier_rmse"] < 1e-9, r.reference_at_convergence
    assert r.rows["small_gicp"]["agrees"] is True and r.rows["small_gicp"]["better_fit"] is None


def test_a_gate_past_what_a_float_squares_is_a_reason_on_a_row_not_a_bug(tmp_path, capsys):
    """``--max-distance 1e160``: the capped RMS of the better-fit test squared the gate (OverflowError: exit 1), and
    KISS-ICP's map size did too (its row failed with "Numerical result out of range")."""
    from pcreg.cli import main

    a, b = _surface()
    np.save(tmp_path / "a.npy", a)
    np.save(tmp_path / "b.npy", b)
    args = ["crosscheck", str(tmp_path / "a.npy"), str(tmp_path / "b.npy"), "--max-distance", "1e160", "--json"]
    with_kiss = importlib.util.find_spec("kiss_icp") is not None
    assert main([*args, "--with", "pycpd" + (",kiss-icp" if with_kiss else "")]) == 0
    out = capsys.readouterr().out
    if with_kiss:
        assert "its map would reserve" in out and "Numerical result" not in out, out


def test_kiss_icps_replayed_iterations_are_timed_and_a_long_replay_is_said_under_its_row():
    """KISS-ICP's iterations are counted and traced by a second run, one call a step, each step's pose scored on
    the clouds: on a LiDAR-sized cloud (200,000 points) 53 of the command's 64 s, which its row's s (its own
    call's 11 s) did not show. The replay's time is kept with the row; where it is longer than the row's s (and
    a second), a line under the row says so."""
    pytest.importorskip("kiss_icp")
    from pcreg import ICPOptions
    from pcreg.commands.crosscheck import format_table
    from pcreg.implementations.suite import builtin_cases

    c = next(c for c in builtin_cases()[0] if c.name == "3d-random")
    r = crosscheck_implementations(c.source, c.target, implementations=["kiss-icp"],
                                   options=ICPOptions(max_correspondence_distance=c.max_correspondence_distance))
    out = r.to_dict()
    row = out["implementations"]["kiss-icp"]
    replay = row["info"]["trace_seconds"]
    assert replay > 0 and row["iterations"] >= 1
    said = "its iterations, replayed one call a step to count and trace them, took a further"
    assert (said in format_table(out)) is (replay > max(1.0, row["seconds"]))
    row["info"]["trace_seconds"], row["seconds"] = 53.0, 11.0  # the LiDAR-sized cloud's figures
    assert f"{said} 53.0 s (its s is its own call's)" in format_table(out)
