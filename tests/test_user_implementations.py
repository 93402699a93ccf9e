"""A researcher's own ICP that misbehaves (``py:`` and ``cmd:``): its row says what went wrong in one line,
the other implementations still report, and the command neither ends with another status nor hangs."""

import json
import os
import subprocess
import sys
import threading
import warnings

import numpy as np
import pytest

from pcreg import ICPOptions
from pcreg.implementations.crosscheck import crosscheck_implementations


def _clouds(d: int = 2):
    tgt = np.random.default_rng(0).uniform(-5, 5, (100, d))
    return tgt + 0.1, tgt


def test_a_module_that_exits_or_changes_directory_is_its_row_and_the_next_one_runs(on_path):
    """sys.exit at a module's import, or in a property of what a function returned, ended the cross-check with
    that status (3 read as "registration refused"); a function that changed directory made the next
    implementation's relative program path and module unfindable."""
    (on_path / "exits_on_import.py").write_text("import sys\nsys.exit(3)\n")
    (on_path / "mine.py").write_text(
        "import os, sys\n"
        "def wanders(source, target, *, init, **kw):\n"
        "    os.chdir(os.sep)\n"
        "    return init\n"
        "class Result:\n"
        "    @property\n"
        "    def matrix(self):\n"
        "        sys.exit(4)\n"
        "def exits_late(source, target, *, init, **kw):\n"
        "    return Result()\n"
        "def identity(source, target, *, init, **kw):\n"
        "    return init\n")
    (on_path / "ident.py").write_text("import sys\nopen(sys.argv[1], 'w').write('1 0 0\\n0 1 0\\n0 0 1\\n')\n")
    program = f'cmd:"{sys.executable} ident.py {{out}}"'
    specs = ["py:exits_on_import:f", "py:mine:exits_late", "py:mine:wanders", program, "py:mine:identity"]
    src, tgt = _clouds()
    r = crosscheck_implementations(src, tgt, implementations=["reference", *specs],
                                   options=ICPOptions(max_correspondence_distance=1.0))
    rows = r.rows
    assert rows["py:exits_on_import:f"]["error"] == "cannot import exits_on_import: called sys.exit(3)"
    assert rows["py:mine:exits_late"]["error"] == "called sys.exit(4); a function returns its matrix"
    for name in ("py:mine:wanders", program, "py:mine:identity"):
        assert rows[name]["status"] == "ok" and not rows[name]["agrees"], rows[name]
    assert rows["reference"]["error"] is None


def test_a_module_that_raises_keyboardinterrupt_on_import_is_its_row_not_an_interrupt(tmp_path):
    """No signal came: the command printed "interrupted" and exited 130 with no report."""
    (tmp_path / "stops.py").write_text("raise KeyboardInterrupt\n")
    src, tgt = _clouds(3)
    np.save(tmp_path / "t.npy", tgt)
    np.save(tmp_path / "s.npy", src)
    p = subprocess.run([sys.executable, "-m", "pcreg.cli", "crosscheck", "t.npy", "s.npy", "--with",
                        "reference,py:stops:align", "--max-distance", "1", "--json"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    row = json.loads(p.stdout)["implementations"]["py:stops:align"]
    assert row["error"] == "cannot import stops: raised KeyboardInterrupt (no interrupt came)"


def test_a_reported_count_of_400_digits_is_refused_in_a_short_line(on_path):
    """float() of it overflowed: the row said "int too large to convert to float", naming nothing."""
    (on_path / "counts.py").write_text(
        "def align(source, target, *, init, **kw):\n"
        "    return {'matrix': init, 'iterations': 10 ** 400}\n")
    src, tgt = _clouds()
    r = crosscheck_implementations(src, tgt, implementations=["reference", "py:counts:align"],
                                   options=ICPOptions(max_correspondence_distance=1.0))
    error = r.rows["py:counts:align"]["error"]
    assert error.startswith("iterations must be in 0..100000, got 1000") and len(error) < 100, error


@pytest.mark.parametrize("template, said", [
    ("sh -c 'echo {' {out}", "cannot read the placeholders of 'echo {'"),
    ("sh -c 'echo }' {out}", "cannot read the placeholders of 'echo }'"),
    ("awk '{print}' {out}", "unknown placeholder {print}"),
    ("prog {out!r}", "unknown placeholder {out!r}"),
    ("prog {out:>40}", "unknown placeholder {out:>40}"),
])
def test_a_template_with_a_lone_brace_or_a_formatted_placeholder_is_bad_input(tmp_path, template, said):
    """A lone brace was a ValueError (exit 1, "a bug in pcreg"); {out!r} ran the program with a quoted path."""
    src, tgt = _clouds(3)
    np.save(tmp_path / "t.npy", tgt)
    np.save(tmp_path / "s.npy", src)
    p = subprocess.run([sys.executable, "-m", "pcreg.cli", "crosscheck", "t.npy", "s.npy", "--with",
                        f'reference,cmd:"{template}"', "--json"], cwd=tmp_path, capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 2, p.stderr
    assert p.stdout == "" and said in p.stderr and "a literal brace is written {{ or }}" in p.stderr, p.stderr
    assert len(p.stderr.strip().splitlines()) == 1, p.stderr


def test_an_empty_output_file_is_said_so_without_a_warning(tmp_path):
    """It was "output matrix is 0x1, expected 3x3", after numpy's warning printed with its source line."""
    (tmp_path / "empty.py").write_text("import sys\nopen(sys.argv[1], 'w').write('# nothing\\n')\n")
    spec = f'cmd:"{sys.executable} {tmp_path / "empty.py"} {{out}}"'
    src, tgt = _clouds()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = crosscheck_implementations(src, tgt, implementations=["reference", spec],
                                       options=ICPOptions(max_correspondence_distance=1.0))
    assert r.rows[spec]["error"] == "wrote an empty output matrix"


@pytest.mark.skipif(not hasattr(os, "setsid") or not hasattr(os, "mkfifo"), reason="needs setsid and FIFOs")
def test_a_process_left_outside_the_group_holding_stderr_is_no_traceback(tmp_path, monkeypatch):
    """A program's child that left its process group (setsid) kept the stderr pipe; the pipe was closed under
    the reader thread, which printed a traceback ("I/O operation on closed file") when the child wrote."""
    fifo = tmp_path / "go"
    os.mkfifo(fifo)
    (tmp_path / "escape.py").write_text(
        "import os, sys\n"
        "r, w = os.pipe()\n"
        "if os.fork() == 0:\n"
        "    os.setsid()\n"
        "    os.write(w, b'x')\n"
        f"    open({str(fifo)!r}).read()\n"
        "    sys.stderr.write('late\\n')\n"
        "    sys.stderr.flush()\n"
        "    os._exit(0)\n"
        "os.read(r, 1)\n"
        "open(sys.argv[1], 'w').write('1 0 0\\n0 1 0\\n0 0 1\\n')\n")
    failures = []
    monkeypatch.setattr(threading, "excepthook", failures.append)
    spec = f'cmd:"{sys.executable} {tmp_path / "escape.py"} {{out}}"'
    src, tgt = _clouds()
    r = crosscheck_implementations(src, tgt, implementations=["reference", spec],
                                   options=ICPOptions(max_correspondence_distance=1.0))
    readers = [t for t in threading.enumerate() if t.name == "pcreg-cmd-stderr"]
    with open(fifo, "w") as go:  # the child writes on the stderr it kept, and ends
        go.write("go")
    for t in readers:
        t.join()
    assert r.rows[spec]["status"] == "ok", r.rows[spec]
    assert readers and not failures, [f.exc_value for f in failures]


def test_a_tensor_returned_is_read_as_its_array(on_path):
    """An object numpy reads through __array__ (a torch tensor) was "returned neither a matrix nor an object
    with 'matrix'"."""
    (on_path / "tensors.py").write_text(
        "import numpy as np\n"
        "class Tensor:\n"
        "    def __init__(self, a):\n"
        "        self.a = a\n"
        "    def __array__(self, dtype=None, copy=None):\n"
        "        return np.asarray(self.a, dtype=dtype)\n"
        "def align(source, target, *, init, **kw):\n"
        "    return Tensor(init + [[0, 0, 0.1], [0, 0, 0], [0, 0, 0]])\n")
    src, tgt = _clouds()
    r = crosscheck_implementations(src, tgt, implementations=["reference", "py:tensors:align"],
                                   options=ICPOptions(max_correspondence_distance=1.0))
    row = r.rows["py:tensors:align"]
    assert row["status"] == "ok" and row["matrix"][0][2] == pytest.approx(0.1), row
    assert row["iterations"] is None and not row["agrees"]


def test_a_long_last_line_on_stderr_is_shortened_with_a_mark(tmp_path):
    """Its first 200 characters read as the whole line."""
    (tmp_path / "talks.py").write_text("import sys\nsys.stderr.write('solver: ' + 'e' * 1000 + '\\n')\nsys.exit(5)\n")
    spec = f'cmd:"{sys.executable} {tmp_path / "talks.py"} {{out}}"'
    src, tgt = _clouds()
    r = crosscheck_implementations(src, tgt, implementations=["reference", spec],
                                   options=ICPOptions(max_correspondence_distance=1.0))
    assert r.rows[spec]["error"] == "exit status 5: solver: " + "e" * 189 + "..."


def test_a_thread_a_function_leaves_running_does_not_hold_the_command_at_exit(tmp_path):
    """Python's exit waited for the function's thread: the report printed, the command never ended."""
    (tmp_path / "spawns.py").write_text(
        "import threading\n"
        "def align(source, target, *, init, **kw):\n"
        "    threading.Thread(target=threading.Event().wait, name='solver-pool').start()\n"
        "    return init\n")
    src, tgt = _clouds(3)
    np.save(tmp_path / "t.npy", tgt)
    np.save(tmp_path / "s.npy", src)
    p = subprocess.run([sys.executable, "-m", "pcreg.cli", "crosscheck", "t.npy", "s.npy", "--with",
                        "reference,py:spawns:align", "--max-distance", "1", "--json"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=120)  # without the fix: never ends
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["implementations"]["py:spawns:align"]["status"] == "ok"
    assert "(solver-pool): ended with the process" in p.stderr


@pytest.mark.parametrize("spec, said", [
    ("py:nosuchmodule:align", "no module named 'nosuchmodule' in the current directory or on Python's path"),
    ("py:mypkg.nosuch:align", "no module named 'mypkg.nosuch'"),
    ("py:mypkg:nosuch", "mypkg has no callable 'nosuch'"),
    ("cmd:nosuch-icp-program {source} {target} {out}", "no program 'nosuch-icp-program' on PATH"),
    ("cmd:./nosuch {out}", "no program './nosuch'"),
    ("cmd:./plain.txt {out}", "'./plain.txt' is not executable"),
])
def test_a_misspelt_module_function_or_program_is_bad_input_before_anything_runs(tmp_path, spec, said):
    """They were rows that failed, and the cross-check exited 0 after running every other implementation: a
    CI job with a misspelt name passed. A module that exists but fails in its own imports is still its row."""
    (tmp_path / "mypkg").mkdir()
    (tmp_path / "mypkg" / "__init__.py").write_text("")
    (tmp_path / "mypkg" / "broken.py").write_text("import nosuch_dependency_of_it\n")
    (tmp_path / "plain.txt").write_text("")
    src, tgt = _clouds(3)
    np.save(tmp_path / "t.npy", tgt)
    np.save(tmp_path / "s.npy", src)
    base = [sys.executable, "-m", "pcreg.cli", "crosscheck", "t.npy", "s.npy", "--max-distance", "1", "--json"]
    p = subprocess.run([*base, "--with", f"reference,{spec}"], cwd=tmp_path, capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 2 and p.stdout == "", p.stderr
    assert p.stderr.strip() == f"pcreg: error: {spec}: {said}" + (
        " (run pcreg from the folder that holds it, or install it)" if "current directory" in said else
        " (the path is read from the current directory)" if "'./nosuch'" in said else
        " (chmod +x it, or name its interpreter first)" if "executable" in said else "")
    p = subprocess.run([*base, "--with", "reference,py:mypkg.broken:align"], cwd=tmp_path, capture_output=True,
                       text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    row = json.loads(p.stdout)["implementations"]["py:mypkg.broken:align"]
    assert row["error"] == "cannot import mypkg.broken: ModuleNotFoundError: No module named 'nosuch_dependency_of_it'"


def test_numpy_error_handling_and_warning_filters_a_function_sets_are_put_back(on_path):
    """A function that called np.seterr(all="raise") (and one whose import made every warning an error) left it so:
    pycpd, run next, failed with "underflow encountered in exp", its row blamed for the other's change, and the
    caller's numpy raised on every underflow after the cross-check."""
    pytest.importorskip("pycpd")
    (on_path / "strict.py").write_text(
        "import warnings\n"
        "import numpy as np\n"
        "warnings.simplefilter('error')\n"
        "def f(source, target, *, init, **kw):\n"
        "    np.seterr(all='raise')\n"
        "    return init\n")
    src, tgt = _clouds(3)
    before = np.geterr()
    r = crosscheck_implementations(src, tgt, implementations=["py:strict:f", "pycpd"],
                                   options=ICPOptions(max_correspondence_distance=1.0))
    assert r.rows["py:strict:f"]["status"] == "ok"
    assert r.rows["pycpd"]["error"] is None and r.rows["pycpd"]["status"] == "ok", r.rows["pycpd"]["error"]
    assert np.geterr() == before
    assert ("error", None, Warning, None, 0) not in warnings.filters  # what simplefilter("error") puts first


def test_a_function_that_closes_sys_stdout_is_its_row_and_the_report_is_printed(on_path, capsys):
    """``sys.stdout.close()`` in a function closed the capture of what it printed: reading the capture raised
    ValueError, and ``pcreg crosscheck --json`` ended as a bug in pcreg (exit 1) without its report."""
    from pcreg.cli import main

    (on_path / "closer.py").write_text(
        "import sys\n"
        "def f(source, target, *, init, **kw):\n"
        "    print('said before closing')\n"
        "    sys.stdout.close()\n"
        "    return init\n")
    src, tgt = _clouds(2)
    np.save(on_path / "s.npy", src)
    np.save(on_path / "t.npy", tgt)
    rc = main(["crosscheck", "t.npy", "s.npy", "--with", "reference,py:closer:f", "--max-distance", "1", "--json"])
    out = capsys.readouterr().out
    assert rc == 0
    row = json.loads(out)["implementations"]["py:closer:f"]
    assert row["status"] == "ok" and row["info"]["said"] == ["said before closing"]


@pytest.mark.parametrize("spec", ["open3D", "py:nosuch:f", "cmd:nosuchprogram {out}"])
def test_a_misspelt_name_in_a_suite_is_bad_input_before_any_case(tmp_path, capsys, spec):
    """``crosscheck --suite`` with a name no implementation answers to ran every case, each a row that blamed the
    reference for it ("reference | no | py:nosuch:f: no module named ..."), exited 0 and wrote the results."""
    from pcreg.cli import main

    out = tmp_path / "suite"
    assert main(["crosscheck", "--suite", str(out), "--with", f"reference,{spec}"]) == 2
    assert spec.split(" ")[0].removeprefix("cmd:") in capsys.readouterr().err
    assert not out.exists() or not any(out.iterdir())
