"""Cross-checks of many ICP implementations: the registry, the floors, user programs, test vectors, suites."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pcreg import ICPOptions
from pcreg import transforms as tf
from pcreg.implementations.suite import builtin_cases, edge_cloud_pair, export_suite, load_suite, run_suite, write_results
from pcreg.implementations.crosscheck import (FIXED_POINT_TOLERANCE, STEP_TOLERANCE, crosscheck_implementations, load_cloud,
                               trace_divergence)
from pcreg.implementations import BUILTIN, DEFAULT, Pinned, get, parse_list
from pcreg.implementations.builtin import Reference

ROOT = Path(__file__).resolve().parent.parent
ROW_KEYS = {"matrix", "iterations", "fitness", "inlier_rmse", "converged", "seconds", "comparability",
            "rotation_disagreement_deg", "translation_disagreement", "agrees", "error"}


def check_floors(report, *, min_running=6):
    rows = report.rows
    running = [n for n, r in rows.items() if r["status"] == "ok"]
    assert len(running) >= min_running, {n: r["error"] for n, r in rows.items()}
    for name, r in rows.items():
        assert ROW_KEYS <= set(r), name
        if r["status"] != "ok":
            continue
        if r["comparability"] == "step":
            assert r["matrix_relative_disagreement"] <= STEP_TOLERANCE, (name, r["matrix_relative_disagreement"])
            assert r["agrees"], name
        elif r["comparability"] == "fixed-point":
            assert r["matrix_relative_disagreement"] <= FIXED_POINT_TOLERANCE, (name, r["matrix_relative_disagreement"])
            assert r["agrees"], name
    return running


@pytest.fixture(scope="module")
def edge_report():
    src, tgt, truth = edge_cloud_pair(max_points=500)
    return crosscheck_implementations(src, tgt, implementations=DEFAULT,
                                      options=ICPOptions(max_correspondence_distance=5.0, max_iteration=60), truth=truth)


def test_six_implementations_meet_their_floors_on_a_2d_edge_cloud(edge_report):
    running = check_floors(edge_report)
    assert {"reference", "open3d", "open3d-tensor", "small_gicp", "kiss-icp", "pycpd"} <= set(running)
    rows = edge_report.rows
    # Open3D (legacy and tensor) follow the reference step for step: same poses, same iteration count.
    for name in ("open3d", "open3d-tensor"):
        assert rows[name]["divergence"] is None and rows[name]["iterations"] == rows["reference"]["iterations"]
    # Surface objectives need 3-D surfaces: refused in 2-D, in one line.
    assert "z = 0" in rows["small_gicp-plane"]["error"] or "3-D" in rows["small_gicp-plane"]["error"]
    # The edge clouds are different samples of the same edges: the reference lands within a pixel of the warp.
    assert rows["reference"]["truth_translation"] < 1.0 and rows["reference"]["truth_rotation_deg"] < 0.2


def test_json_layout_of_a_cloud_crosscheck(edge_report):
    out = json.loads(json.dumps(edge_report.to_dict()))
    ref = out["implementations"]["reference"]
    assert ref["agrees"] is True and ref["error"] is None and ref["matrix_relative_disagreement"] == 0.0
    assert len(ref["matrix"]) == 3 and isinstance(ref["iterations"], int) and ref["seconds"] > 0
    assert ref["comparability"] == "step" and ref["settings"]["max_correspondence_distance"] == 5.0
    assert "corner_disagreement" in out["implementations"]["open3d"]
    assert out["reference_at_convergence"]["converged"] is True


@pytest.mark.slow
@pytest.mark.data
def test_six_implementations_meet_their_floors_on_the_lidar_pair(shared_data):
    from pcreg.registration.api import voxel_downsample

    scans = shared_data / "scans"
    src = voxel_downsample(load_cloud(scans / "source.ply"), 1.0)
    tgt = voxel_downsample(load_cloud(scans / "target.ply"), 1.0)
    truth = np.loadtxt(scans / "T_target_source.txt")
    report = crosscheck_implementations(src, tgt, implementations=DEFAULT,
                                        options=ICPOptions(max_correspondence_distance=1.0, max_iteration=60), truth=truth)
    running = check_floors(report)
    assert len(running) == len(DEFAULT)
    rows = report.rows
    # probreg's rigid CPD with update_scale=False keeps sigma^2 too large (its update lacks the factor 2 of
    # the cross term) and stops far from the others: the cross-check reports it as disagreeing.
    assert not rows["probreg-cpd"]["agrees"] and rows["probreg-cpd"]["translation_disagreement"] > 0.5
    assert rows["reference"]["truth_translation"] < 0.2 and rows["reference"]["truth_rotation_deg"] < 2.5


def test_divergence_names_the_iteration_and_the_cause():
    rng = np.random.default_rng(3)
    tgt = rng.uniform(-10, 10, (400, 2))
    src = tf.apply(np.linalg.inv(tf.rigid2d(6, 0.5, -0.4)), tgt) + rng.normal(scale=0.05, size=tgt.shape)
    p = Pinned(src, tgt, np.eye(3), 2.0, 30)
    a = Reference().run(p, trace=True)
    same = get("open3d-tensor").run(p, trace=True)
    assert trace_divergence(a.trace, same.trace) is None
    narrow = Reference().run(p.replace(max_correspondence_distance=0.5), trace=True)
    d = trace_divergence(a.trace, narrow.trace)
    assert d["iteration"] == 0 and "different correspondences" in d["cause"]
    fewer = Reference().run(p.replace(relative_rmse=1e-1, relative_fitness=1.0), trace=True)
    d = trace_divergence(a.trace, fewer.trace)
    assert "stopping rule" in d["cause"]


def test_an_implementation_returns_the_registration_result_that_icp_returns(tmp_path):
    """One result type for a registration: an implementation's result is a RegistrationResult named by its
    frames, its trace IcpIterations without point arrays; what a user's function does not report is
    NaN, -1 or None there and None in the cross-check row."""
    from pcreg.registration.result import IcpIteration, RegistrationResult

    rng = np.random.default_rng(3)
    tgt = rng.uniform(-10, 10, (300, 2))
    src = tf.apply(np.linalg.inv(tf.rigid2d(4, 0.3, -0.2)), tgt)
    p = Pinned(src, tgt, np.eye(3), 2.0, 30)
    r = get("open3d-tensor").run(p, trace=True)
    assert isinstance(r, RegistrationResult) and r.backend == "open3d-tensor" and r.frames == "T_target_source"
    np.testing.assert_array_equal(r.T_target_source, r.matrix)
    assert r.trace and all(isinstance(s, IcpIteration) and s.source_points is None for s in r.trace)
    assert [s.iteration for s in r.trace] == list(range(len(r.trace)))
    assert np.isnan(r.trace[0].fitness)  # Open3D's callback starts after the first update
    assert r.trace[-1].fitness == pytest.approx(r.fitness)

    (tmp_path / "bareimpl.py").write_text("def bare(source, target, *, init, **params):\n    return init\n")
    sys.path.insert(0, str(tmp_path))
    try:
        bare = get("py:bareimpl:bare").run(p)
        row = crosscheck_implementations(src, tgt, implementations=["reference", "py:bareimpl:bare"],
                                         options=ICPOptions(max_correspondence_distance=2.0)).rows["py:bareimpl:bare"]
    finally:
        sys.path.remove(str(tmp_path))
    assert np.isnan(bare.fitness) and np.isnan(bare.inlier_rmse) and bare.iterations == -1 and bare.converged is None
    assert bare.backend == "py:bareimpl:bare" and bare.trace == ()
    assert (row["fitness"], row["inlier_rmse"], row["iterations"], row["converged"]) == (None, None, None, None)
    assert "fitness=nan" in repr(bare)


def test_a_python_function_that_declares_an_unknown_comparability_is_its_rows_error(tmp_path):
    """A ``py:`` function's ``comparability`` other than step, fixed-point or objective (a typo) is its row's
    error, as a ``cmd:`` program's in ``{out}.json`` is: it was read as "step" without a word, and the row compared
    the function's pose step for step with a tolerance the function had not asked for."""
    (tmp_path / "typoimpl.py").write_text("def run(source, target, *, init, **params):\n    return init\n"
                                          "run.comparability = 'fixed_point'\n"
                                          "def fine(source, target, *, init, **params):\n    return init\n"
                                          "fine.comparability = 'fixed-point'\n")
    tgt = np.random.default_rng(0).uniform(-5, 5, (100, 3))
    sys.path.insert(0, str(tmp_path))
    try:
        r = crosscheck_implementations(tgt + 0.1, tgt, implementations=["reference", "py:typoimpl:run",
                                                                         "py:typoimpl:fine"],
                                       options=ICPOptions(max_correspondence_distance=1.0))
    finally:
        sys.path.remove(str(tmp_path))
    typo, fine = r.rows["py:typoimpl:run"], r.rows["py:typoimpl:fine"]
    assert typo["status"] == "failed" and "comparability must be one of" in typo["error"], typo
    assert "'fixed_point'" in typo["error"] and not typo["agrees"]
    assert fine["error"] is None and fine["comparability"] == "fixed-point"


@pytest.mark.parametrize("offset", [0.0, 1e6])
def test_an_objective_row_is_judged_alike_wherever_the_clouds_lie(tmp_path, offset):
    """The same clouds, and an implementation whose pose is the reference's turned 0.1 degree about the clouds'
    centre, agree by objective near the origin and 1e6 away (georeferenced coordinates) alike, judged by where the
    two put the source's centroid: the matrices' translations differ by the turn times the distance to the origin
    (2,468 units at 1e6), and the row disagreed there."""
    (tmp_path / "turnedimpl.py").write_text(
        "import numpy as np\n"
        "import pcreg\n"
        "from pcreg import transforms as tf\n"
        "def run(source, target, *, init, max_correspondence_distance, **params):\n"
        "    T = pcreg.icp(source, target, pcreg.ICPOptions(max_correspondence_distance=max_correspondence_distance),\n"
        "                  init=init).matrix\n"
        "    R = np.eye(4)\n"
        "    R[:3, :3] = tf.rigid2d(0.1)\n"
        "    R[2, :] = [0, 0, 1, 0]\n"
        "    return tf.about_point(R, tuple(target.mean(axis=0))) @ T\n"
        "run.comparability = 'objective'\n")
    rng = np.random.default_rng(0)
    target = rng.uniform(-10, 10, (400, 3)) + offset
    T = tf.about_point(np.eye(4), (offset,) * 3)
    T[:3, 3] += [0.3, -0.2, 0.1]
    sys.path.insert(0, str(tmp_path))
    try:
        r = crosscheck_implementations(tf.apply(np.linalg.inv(T), target), target,
                                       implementations=["reference", "py:turnedimpl:run"],
                                       options=ICPOptions(max_correspondence_distance=2.0), truth=T)
    finally:
        sys.path.remove(str(tmp_path))
    row = r.rows["py:turnedimpl:run"]
    assert row["error"] is None and row["rotation_disagreement_deg"] == pytest.approx(0.1, rel=1e-6)
    assert row["centroid_disagreement"] < 0.01 and row["agrees"], row
    assert row["translation_disagreement"] == pytest.approx(np.linalg.norm(
        np.subtract(row["matrix"], r.rows["reference"]["matrix"])[:3, 3]))  # the matrices' translations, as before


def test_parse_list_keeps_quoted_commas_and_expands_all():
    items = parse_list('reference,cmd:"prog --x=1,2 {source} {out}",py:m:f,all')
    assert items[1] == 'cmd:"prog --x=1,2 {source} {out}"' and items[2] == "py:m:f"
    assert set(DEFAULT) <= set(items) and len(items) == len(set(items))


def test_missing_library_is_reported_not_fatal(monkeypatch):
    monkeypatch.setattr(BUILTIN["small_gicp"], "requires", ("no_such_module_xyz",))
    rng = np.random.default_rng(0)
    tgt = rng.uniform(-5, 5, (200, 3))
    r = crosscheck_implementations(tgt + 0.05, tgt, implementations=["reference", "small_gicp", "open3d"],
                                   options=ICPOptions(max_correspondence_distance=1.0))
    assert r.rows["small_gicp"]["status"] == "missing" and "no_such_module_xyz" in r.rows["small_gicp"]["error"]
    assert r.rows["open3d"]["agrees"]


# ---------------------------------------------------------------------------------------------------
# User implementations: py: and cmd: (a C program compiled here, and broken programs)
# ---------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def icp_min(tmp_path_factory):
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler (cc/gcc) on PATH to build tools/icp_min.c")
    exe = tmp_path_factory.mktemp("icp_min") / "icp_min"
    subprocess.run([cc, "-O2", "-o", str(exe), str(ROOT / "tools" / "icp_min.c"), "-lm"], check=True)
    return exe


@pytest.mark.parametrize("dim", [2, 3])
def test_external_c_icp_agrees_step_for_step_and_a_wrong_one_disagrees(icp_min, dim):
    rng = np.random.default_rng(dim)
    tgt = rng.uniform(-10, 10, (300, dim))
    T = tf.rigid2d(5, 0.3, -0.2) if dim == 2 else np.array(
        [[0.99875, -0.0499792, 0, 0.3], [0.0499792, 0.99875, 0, -0.2], [0, 0, 1, 0.1], [0, 0, 0, 1.0]])
    if dim == 3:
        u, _, vt = np.linalg.svd(T[:3, :3])
        T[:3, :3] = u @ vt
    src = tf.apply(np.linalg.inv(T), tgt) + rng.normal(scale=0.03, size=tgt.shape)
    good = f'cmd:"{icp_min} {{source}} {{target}} {{init}} {{out}} {{params}}"'
    wrong = f'cmd:"{icp_min} {{source}} {{target}} {{init}} {{out}} {{params}} --wrong"'
    r = crosscheck_implementations(src, tgt, implementations=["reference", good, wrong],
                                   options=ICPOptions(max_correspondence_distance=2.0, max_iteration=40))
    g, w = r.rows[good], r.rows[wrong]
    assert g["error"] is None and g["comparability"] == "step"
    assert g["matrix_relative_disagreement"] <= STEP_TOLERANCE and g["agrees"]
    assert g["iterations"] == r.rows["reference"]["iterations"]
    assert g["fitness"] == pytest.approx(r.rows["reference"]["fitness"], abs=1e-12)
    assert w["error"] is None and not w["agrees"] and w["rotation_disagreement_deg"] > 1.0



def test_a_program_that_writes_its_matrix_as_csv_is_read(tmp_path):
    """A cmd: program that writes {out} with commas (``numpy.savetxt(..., delimiter=",")``): its row read
    "unreadable output matrix". It is read as the same matrix with spaces: one that returns the reference's own
    answer agrees with it, and an empty field between two commas is still that row's error."""
    tgt = np.random.default_rng(0).uniform(-5, 5, (200, 2))
    src = tgt - [0.2, 0.1]
    ref = crosscheck_implementations(src, tgt, implementations=["reference"],
                                     options=ICPOptions(max_correspondence_distance=1.0)).rows["reference"]["matrix"]
    script = tmp_path / "csv_icp.py"
    script.write_text("import sys, numpy as np\n"
                      f"np.savetxt(sys.argv[1], np.array({np.asarray(ref).tolist()!r}), delimiter=',')\n")
    gap = tmp_path / "gap.py"
    gap.write_text("import sys\nopen(sys.argv[1], 'w').write('1,,0\\n0,1,0\\n0,0,1\\n')\n")
    csv, bad = f'cmd:"{sys.executable} {script} {{out}}"', f'cmd:"{sys.executable} {gap} {{out}}"'
    r = crosscheck_implementations(src, tgt, implementations=["reference", csv, bad],
                                   options=ICPOptions(max_correspondence_distance=1.0))
    assert r.rows[csv]["error"] is None and r.rows[csv]["agrees"], r.rows[csv]
    np.testing.assert_array_equal(r.rows[csv]["matrix"], ref)
    assert "unreadable output matrix" in r.rows[bad]["error"], r.rows[bad]

def _ended(pid: int) -> bool:
    """Whether process ``pid`` is gone or a zombie (killed, not reaped yet)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return True
    return state in ("Z", "X")


def _ends(pid: int) -> bool:
    """Whether process ``pid`` ends within 30 s: SIGKILL was sent before the row was made, and lands soon."""
    import time

    deadline = time.monotonic() + 30
    while not _ended(pid) and time.monotonic() < deadline:
        time.sleep(0.01)
    return _ended(pid)


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads a process's state in /proc")
def test_a_program_past_its_time_limit_ends_with_its_children(tmp_path):
    """A cmd: program that starts a child and hangs: at the time limit its row says so, and the child it
    started is killed with it (it once outlived the cross-check)."""
    from pcreg.implementations.crosscheck import crosscheck_implementations

    script = tmp_path / "parent.py"
    script.write_text("import subprocess, sys, threading\n"
                      "child = subprocess.Popen([sys.executable, '-c', 'import threading; threading.Event().wait()'])\n"
                      f"open({str(tmp_path / 'child.pid')!r}, 'w').write(str(child.pid))\n"
                      "threading.Event().wait()\n")
    spec = f'cmd:"{sys.executable} {script} {{out}}"'
    tgt = np.random.default_rng(0).uniform(-5, 5, (100, 2))
    r = crosscheck_implementations(tgt + 0.1, tgt, implementations=["reference", spec],
                                   options=ICPOptions(max_correspondence_distance=1.0), timeout=8)
    assert "timed out after 8 s" in r.rows[spec]["error"]
    assert _ends(int((tmp_path / "child.pid").read_text()))


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads a process's state in /proc")
def test_a_program_that_leaves_a_fifo_a_child_or_a_flood_of_output_is_one_row(tmp_path):
    """A FIFO at {out} blocked the read for ever; a child left running with the output streams open made a
    finished program's row "timed out"; what a program prints is not kept in memory (its last stderr line
    is what the row says)."""
    from pcreg.implementations.crosscheck import crosscheck_implementations

    py = sys.executable
    scripts = {
        "fifo": "import os, sys; os.mkfifo(sys.argv[1])",
        "child": ("import subprocess, sys; open(sys.argv[1], 'w').write('1 0 0.1\\n0 1 0\\n0 0 1\\n'); "
                  f"c = subprocess.Popen([sys.executable, '-c', 'import threading; threading.Event().wait()']); "
                  f"open({str(tmp_path / 'child.pid')!r}, 'w').write(str(c.pid))"),
        "flood": ("import sys; [sys.stdout.write('x' * 1000 + '\\n') for _ in range(20000)]; "
                  "[sys.stderr.write('y' * 1000 + '\\n') for _ in range(20000)]; sys.stderr.write('the last word\\n'); "
                  "sys.exit(4)"),
    }
    specs = {}
    for name, code in scripts.items():
        (tmp_path / f"{name}.py").write_text(code)
        specs[name] = f'cmd:"{py} {tmp_path / name}.py {{out}}"'
    tgt = np.random.default_rng(0).uniform(-5, 5, (100, 2))
    r = crosscheck_implementations(tgt + 0.1, tgt, implementations=["reference", *specs.values()],
                                   options=ICPOptions(max_correspondence_distance=1.0), timeout=60)
    assert "not a regular file" in r.rows[specs["fifo"]]["error"]
    assert "error" not in r.rows[specs["child"]] or not r.rows[specs["child"]]["error"], r.rows[specs["child"]]
    assert _ends(int((tmp_path / "child.pid").read_text()))  # killed when its program ended
    assert r.rows[specs["flood"]]["error"] == "exit status 4: the last word"


@pytest.mark.slow
def test_broken_programs_fail_in_one_line_and_the_others_still_run(tmp_path):
    py = sys.executable
    scripts = {
        "exit": "import sys; sys.stderr.write('boom\\n'); sys.exit(3)",
        # never answers (waits for an event nobody sets); the others answer at once, without imports (a bare
        # interpreter took up to 1.3 s to start at a load of 19: the limit of 8 s leaves them room)
        "slow": "import threading; threading.Event().wait()",
        "garbage": "import sys; open(sys.argv[1], 'w').write('not a matrix')",
        "nan": "import sys; open(sys.argv[1], 'w').write('nan nan nan\\n' * 3)",
        "shape": "import sys; open(sys.argv[1], 'w').write('1 0 0 0\\n0 1 0 0\\n0 0 1 0\\n0 0 0 1\\n')",
        # matrices no rigid ICP returns, and a side file of impossible figures
        "scaled": "import sys; open(sys.argv[1], 'w').write('5 0 0\\n0 5 0\\n0 0 1\\n')",
        "reflection": "import sys; open(sys.argv[1], 'w').write('-1 0 0\\n0 1 0\\n0 0 1\\n')",
        "lastrow": "import sys; open(sys.argv[1], 'w').write('1 0 0\\n0 1 0\\n1 2 3\\n')",
        "side": ("import sys, json; open(sys.argv[1], 'w').write('1 0 0\\n0 1 0\\n0 0 1\\n'); "
                 "json.dump({'iterations': 3, 'fitness': 7.5}, open(sys.argv[1] + '.json', 'w'))"),
        "converged": ("import sys, json; open(sys.argv[1], 'w').write('1 0 0\\n0 1 0\\n0 0 1\\n'); "
                      "json.dump({'converged': 'yes'}, open(sys.argv[1] + '.json', 'w'))"),
    }
    specs = {}
    for name, code in scripts.items():
        f = tmp_path / f"{name}.py"
        f.write_text(code)
        specs[name] = f'cmd:"{py} {f} {{out}}"'
    (tmp_path / "userimpl.py").write_text(
        "import numpy as np\n"
        "def identity(source, target, *, init, **params):\n"
        "    return {'matrix': init, 'iterations': 0}\n"
        "def crash(source, target, **kw):\n"
        "    raise RuntimeError('no')\n")
    sys.path.insert(0, str(tmp_path))
    try:
        rng = np.random.default_rng(0)
        tgt = rng.uniform(-5, 5, (200, 2))
        specs["py"] = "py:userimpl:identity"
        specs["pycrash"] = "py:userimpl:crash"
        r = crosscheck_implementations(tgt + 0.1, tgt, implementations=["reference", "open3d", *specs.values()],
                                       options=ICPOptions(max_correspondence_distance=1.0), timeout=8)
    finally:
        sys.path.remove(str(tmp_path))
    rows = r.rows
    assert rows["open3d"]["agrees"]
    assert rows[specs["exit"]]["error"] == "exit status 3: boom"
    assert "timed out after 8 s" in rows[specs["slow"]]["error"]
    assert "unreadable output" in rows[specs["garbage"]]["error"]
    assert "NaN" in rows[specs["nan"]]["error"]
    assert "expected 3x3" in rows[specs["shape"]]["error"]
    assert "not orthonormal (a scale or a shear)" in rows[specs["scaled"]]["error"]
    assert "a reflection" in rows[specs["reflection"]]["error"]
    assert "last row is [1.0, 2.0, 3.0]" in rows[specs["lastrow"]]["error"]
    assert rows[specs["side"]]["error"] == "fitness must be in 0..1, got 7.5"
    assert rows[specs["converged"]]["error"] == "converged must be true or false, got 'yes'"
    assert not any(rows[specs[k]]["agrees"] for k in ("scaled", "reflection", "lastrow", "side", "converged"))
    assert "RuntimeError: no" in rows[specs["pycrash"]]["error"]
    assert rows[specs["py"]]["error"] is None and not rows[specs["py"]]["agrees"]
    for s in specs.values():
        assert "\n" not in (rows[s]["error"] or "")


def test_cmd_protocol_files_are_exactly_as_documented(tmp_path):
    spy = tmp_path / "spy.py"
    spy.write_text(
        "import json, sys, numpy as np\n"
        "src, tgt, init, out, params = sys.argv[1:6]\n"
        "s, t = np.load(src), np.load(tgt)\n"
        "assert s.dtype == np.float64 and s.ndim == 2 and t.shape[1] == s.shape[1]\n"
        "m = np.loadtxt(init)\n"
        "p = json.load(open(params))\n"
        "assert set(p) == {'max_correspondence_distance', 'max_iterations', 'relative_fitness', 'relative_rmse'}\n"
        "np.savetxt(out, m)\n"
        "json.dump({'iterations': 7, 'fitness': 0.5, 'inlier_rmse': 0.25}, open(out + '.json', 'w'))\n")
    spec = f'cmd:"{sys.executable} {spy} {{source}} {{target}} {{init}} {{out}} {{params}}"'
    rng = np.random.default_rng(1)
    tgt = rng.uniform(-5, 5, (100, 3))
    init = np.eye(4)
    init[:3, 3] = [0.1, 0.2, 0.3]
    r = crosscheck_implementations(tgt, tgt, implementations=[spec], init=init,
                                   options=ICPOptions(max_correspondence_distance=1.0))
    row = r.rows[spec]
    assert row["error"] is None, row["error"]
    np.testing.assert_allclose(row["matrix"], init)
    assert (row["iterations"], row["fitness"], row["inlier_rmse"]) == (7, 0.5, 0.25)


# ---------------------------------------------------------------------------------------------------
# Test vectors and suites
# ---------------------------------------------------------------------------------------------------

def test_export_writes_readable_test_vectors_with_the_reference_trace(tmp_path):
    cases, _ = builtin_cases(scans=None)
    pick = [c for c in cases if c.name in ("2d-random", "3d-noise", "3d-collinear")]
    export_suite(tmp_path, pick)
    index = json.loads((tmp_path / "index.json").read_text())
    assert index["cases"] == ["2d-random", "3d-collinear", "3d-noise"] or set(index["cases"]) == {c.name for c in pick}
    d = tmp_path / "3d-noise"
    T = np.load(d / "reference" / "transforms.npy")
    C = np.load(d / "reference" / "correspondences.npy")
    trace = json.loads((d / "reference" / "trace.json").read_text())
    src = np.load(d / "source.npy")
    assert T.shape == (trace["iterations"] + 1, 4, 4) and C.shape == (len(T), len(src)) and C.dtype == np.int64
    np.testing.assert_array_equal(T[-1], np.loadtxt(d / "reference" / "final.txt"))
    np.testing.assert_array_equal(T[0], np.loadtxt(d / "init.txt"))
    assert len((d / "reference" / "correspondences.txt").read_text().splitlines()) == len(T)
    # Replaying one step from the files alone reproduces the next pose (Umeyama on the stored pairs).
    from pcreg.registration.reference import estimate

    tgt = np.load(d / "target.npy")
    ok = C[0] >= 0
    U = estimate(tf.apply(T[0], src)[ok], tgt[C[0][ok]], np.ones(ok.sum()), "rigid")
    np.testing.assert_allclose(U @ T[0], T[1], atol=1e-12)
    # The reference refuses a 3-D line (the rotation about it is undetermined); the refusal is exported.
    assert "collinear" in json.loads((tmp_path / "3d-collinear" / "case.json").read_text())["reference_error"]
    loaded = {c.name: c for c in load_suite(tmp_path)}
    np.testing.assert_array_equal(loaded["3d-noise"].source, src)
    # A hand-edited suite: a parameter of the wrong type or range, or a case named outside the suite, is one line
    from pcreg.errors import InputError

    params = tmp_path / "3d-noise" / "params.json"
    good = params.read_text()
    for change, said in [({"max_iterations": 30.5}, "max_iterations must be an integer"),
                         ({"max_iterations": -3}, "max_iterations must be"),
                         ({"max_correspondence_distance": "1"}, "max_correspondence_distance must be a number"),
                         ({"relative_rmse": float("nan")}, "relative_rmse must be")]:
        params.write_text(json.dumps({**json.loads(good), **change}))
        with pytest.raises(InputError, match=f"params.json: {said}"):
            load_suite(tmp_path)
    params.write_text(good)
    index = tmp_path / "index.json"
    meta = json.loads(index.read_text())
    index.write_text(json.dumps({**meta, "cases": ["../../etc"]}))
    with pytest.raises(InputError, match="case '../../etc' is not the name of a folder in the suite"):
        load_suite(tmp_path)


def test_suite_writes_a_table_and_a_figure(tmp_path):
    cases, skipped = builtin_cases(scans=tmp_path / "none")
    assert "lidar" in skipped
    names = {c.name for c in cases}
    assert {"2d-collinear", "2d-symmetric", "2d-partial", "2d-outliers", "2d-noise", "3d-planar", "3d-symmetric",
            "3d-partial", "3d-outliers", "3d-noise", "2d-edges", "3d-random"} <= names
    pick = [c for c in cases if c.name in ("2d-random", "3d-outliers")]
    rows = run_suite(pick, ["reference", "open3d", "kiss-icp"])
    files = write_results(tmp_path, rows, skipped=skipped)
    md = Path(files["markdown"]).read_text()
    assert "3d-outliers" in md and "kiss-icp" in md and "lidar" in md
    # the table shows the figure a row is judged on: the poses compared about the source's centroid
    assert "| pose_relative_disagreement |" in md and "matrix_relative_disagreement" not in md, md.splitlines()[0]
    assert Path(files["figure"]).stat().st_size > 1000
    assert all(r["agrees"] for r in rows), [(r["case"], r["implementation"], r.get("error")) for r in rows]
    ref = [r for r in rows if r["implementation"] == "reference" and r["case"] == "2d-random"][0]
    assert ref["truth_rotation_deg"] < 1e-6  # exact ground truth


@pytest.mark.slow
def test_command_json_is_the_only_thing_on_stdout(tmp_path):
    rng = np.random.default_rng(2)
    tgt = rng.uniform(-5, 5, (300, 3))
    np.save(tmp_path / "t.npy", tgt)
    np.save(tmp_path / "s.npy", tgt + [0.1, -0.05, 0.02])
    p = subprocess.run([sys.executable, "-m", "pcreg.cli", "crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "s.npy"),
                        "--with", "reference,open3d,open3d-tensor,small_gicp,kiss-icp", "--max-distance", "1",
                        "--max-iterations", "50", "--json", "--record", str(tmp_path / "cc.rrd")],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert set(out["implementations"]) == {"reference", "open3d", "open3d-tensor", "small_gicp", "kiss-icp"}
    assert all(r["agrees"] for r in out["implementations"].values())
    from pcreg.recording.readback import read_recording

    rec = read_recording(tmp_path / "cc.rrd")
    assert "/crosscheck/target" in rec.entities()
    for name, row in out["implementations"].items():
        err = rec.series(f"crosscheck/{name}/error", timeline="crosscheck_iteration")
        clouds = [r for r in rec.get(f"crosscheck/{name}/cloud") if not r.static]
        assert err and clouds, name
        if name != "small_gicp":  # small_gicp reports its final pose only
            assert sorted(err) == list(range(row["iterations"] + 1)), name
        assert err[max(err)] < 1e-6  # every one ends where the reference ends


def test_kiss_icp_keeps_a_target_that_repeats_points_and_refuses_a_map_it_cannot_hold():
    """A target that repeats points (small_gicp's LiDAR target.ply holds 5,032 repeats) asked KISS-ICP's map for
    10**6 points a voxel, which it reserves in every voxel it fills: the row ended in std::bad_alloc (28 GiB
    there). A repeat is dropped by the map and changes no nearest distance, so the map is sized from the
    closest distinct points; a map that would still exceed its memory is refused with the reason."""
    pytest.importorskip("kiss_icp")
    rng = np.random.default_rng(5)
    target = rng.uniform(0, 10, (400, 3))
    target = np.vstack([target, target[:50]])
    source = target[:400] + [0.05, -0.03, 0.02]
    pinned = Pinned(source, target, np.eye(4), 1.0)
    assert get("kiss-icp").settings(pinned)["max_points_per_voxel"] < 10**4
    options = ICPOptions(max_correspondence_distance=1.0, max_iteration=50)
    report = crosscheck_implementations(source, target, implementations=("reference", "kiss-icp"), options=options)
    row = report.rows["kiss-icp"]
    assert row["agrees"], row["error"]
    assert row["info"]["map_dropped_points"] == 50
    close = np.vstack([target[:400], target[0] + [1e-5, 0, 0]])  # 4e10 points a voxel to keep both
    report = crosscheck_implementations(source, close, implementations=("reference", "kiss-icp"), options=options)
    assert report.rows["reference"]["status"] == "ok"
    row = report.rows["kiss-icp"]
    assert row["status"] == "failed" and "GiB to keep every target point" in row["error"], row["error"]
    assert "--voxel-size" in row["error"]


def test_kiss_icp_that_meets_its_criterion_at_its_last_iteration_has_converged(monkeypatch):
    """KISS-ICP's row read "not converged" when its criterion stopped it at exactly its last iteration (the
    iterations counted, not the criterion): the same run one iteration longer said converged."""
    pytest.importorskip("kiss_icp")
    import pcreg.implementations.builtin as builtin

    rng = np.random.default_rng(3)
    target = rng.uniform(0, 10, (300, 3))
    source = target + [0.2, -0.1, 0.05]
    monkeypatch.setattr(builtin, "CONVERGED_ITERATIONS", 1)
    first = get("kiss-icp").run(Pinned(source, target, np.eye(4), 1.0, max_iterations=200), trace=True)
    assert first.converged and 1 < first.iterations < 200
    k = first.iterations
    for limit, converged in ((k, True), (k - 1, False)):
        row = get("kiss-icp").run(Pinned(source, target, np.eye(4), 1.0, max_iterations=limit), trace=True)
        assert (row.iterations, row.converged) == (limit, converged), limit
