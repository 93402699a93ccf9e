"""The command line on hostile invocations and environments: one line on stderr and the documented exit
code, quickly, never an internal error or a wait."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import cv2

import numpy as np
import pytest

from pcreg.cli import main
from _runs import one_line_errors


@pytest.mark.parametrize("argv, names", [([], "register, crosscheck"), (["evaluate"], "classification, rotation")])
def test_no_command_is_one_line(capsys, argv, names):
    assert main(argv) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and names in err[0] and "--help" in err[0]


def test_an_unknown_numba_threading_layer_is_bad_input(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("NUMBA_THREADING_LAYER", "bogus")
    img = tmp_path / "a.png"
    cv2.imwrite(str(img), np.zeros((64, 64, 3), np.uint8))
    assert main(["register", str(img), str(img)]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "NUMBA_THREADING_LAYER='bogus'" in err[0] and "workqueue" in err[0]


def test_a_numba_threading_layer_that_cannot_load_is_bad_input(tmp_path, monkeypatch, capsys):
    """``NUMBA_THREADING_LAYER=tbb`` (or ``safe``) without TBB's library passed the check of its name, then ended the
    command at its first parallel kernel as "a bug in pcreg" (exit 1), or as a refused registration (exit 3)."""
    from pcreg.registration import nn

    monkeypatch.setitem(nn._LAYER_NEEDS, "tbb", ("no_such_pool",))  # as TBB's library absent, wherever it is installed
    monkeypatch.setenv("NUMBA_THREADING_LAYER", "tbb")
    img = tmp_path / "a.png"
    cv2.imwrite(str(img), np.zeros((64, 64, 3), np.uint8))
    assert main(["register", str(img), str(img)]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "NUMBA_THREADING_LAYER='tbb': numba cannot load it" in err[0] and "workqueue" in err[0]
    monkeypatch.setenv("NUMBA_THREADING_LAYER", "forksafe")  # numba's own workqueue will do: taken
    assert nn._layer_missing("forksafe") is None and nn._layer_missing("workqueue") is None


def test_a_tbb_too_old_for_numba_is_refused(monkeypatch):
    """A TBB older than numba takes (2021 update 5, say) imports, and numba then refuses it at its first parallel
    kernel: the check asks numba's own test of the version."""
    from numba.np.ufunc import parallel

    from pcreg.registration import nn

    def too_old():
        raise ImportError("Problem with TBB. Reason: Found TBB_INTERFACE_VERSION = 12050")

    monkeypatch.setattr(parallel, "_check_tbb_version_compatible", too_old)
    assert "12050" in (nn._layer_missing("tbb") or "") and "12050" in (nn._layer_missing("safe") or "")
    assert nn._layer_missing("workqueue") is None


@pytest.mark.parametrize("given", ["0", "-2", "abc", " "])
def test_a_bad_numba_thread_count_is_one_line_before_any_module_loads(tmp_path, monkeypatch, capsys, given):
    """NUMBA_NUM_THREADS=0 ended every command, --version included, in numba's ValueError of 50 lines (exit 1): numba
    reads it on import, which loading the commands does; a value that is no number gave nine lines of warning."""
    monkeypatch.setenv("NUMBA_NUM_THREADS", given)
    assert main(["--version"]) == 2
    err = one_line_errors(capsys)
    assert err == [f"pcreg: error: NUMBA_NUM_THREADS={given!r}: numba's number of threads is a whole number, 1 or more "
                   "(unset it for one a CPU)"]
    for taken in ("1", "+4", " 2 "):  # what numba's int() reads
        monkeypatch.setenv("NUMBA_NUM_THREADS", taken)
        with pytest.raises(SystemExit) as done:
            main(["--version"])
        assert done.value.code == 0


def test_memory_that_runs_out_inside_a_library_is_said_as_out_of_memory(tmp_path, monkeypatch, capsys):
    """Under a memory limit (ulimit -v) OpenCV's "Insufficient memory" and a compiled module that could not be mapped
    when it loaded ended in "internal error, a bug in pcreg" (exit 1): out of memory, exit 2, as a MemoryError is; too
    many open files names the limit, not whichever file (one of pcreg's own modules) was opened last."""
    import errno

    import pcreg.commands.register as command
    from pcreg.cli import _os_error

    img = tmp_path / "a.png"
    cv2.imwrite(str(img), np.zeros((64, 64, 3), np.uint8))
    for raised in (cv2.error("OpenCV(4.10.0) matrix.cpp:73: error: (-4:Insufficient memory) Failed to allocate "
                             "14745600 bytes in function 'OutOfMemoryError'"),
                   ImportError("/x/rerun_bindings.abi3.so: failed to map segment from shared object")):
        def fail(args, raised=raised):
            raise raised

        monkeypatch.setattr(command, "run", fail)
        assert main(["register", str(img), str(img)]) == 2
        err = one_line_errors(capsys)
        assert len(err) == 1 and err[0].startswith("pcreg: error: out of memory ("), err
    monkeypatch.setattr(command, "run", lambda args: (_ for _ in ()).throw(ImportError("No module named 'x'")))
    assert main(["register", str(img), str(img)]) == 1  # a module missing is pcreg's bug, said as one
    capsys.readouterr()
    said = _os_error(OSError(errno.EMFILE, "Too many open files", "/work/pcreg/registration/api.py"))
    assert said.startswith("too many open files (this process may open ") and "api.py" not in said
    # a library on a file system mounted noexec reads "failed to map segment" too, with its reason: not memory
    noexec = ImportError("/mnt/x/cv2.abi3.so: failed to map segment from shared object: Operation not permitted")
    monkeypatch.setattr(command, "run", lambda args: (_ for _ in ()).throw(noexec))
    assert main(["register", str(img), str(img)]) == 1
    capsys.readouterr()
    # and while the commands' modules load, before any command runs (it was a traceback)
    import pcreg.cli as cli

    def unloadable():
        raise ImportError("/x/cv2.abi3.so: failed to map segment from shared object")

    monkeypatch.setattr(cli, "build_parser", unloadable)
    assert main(["register", str(img), str(img)]) == 2
    assert one_line_errors(capsys) == ["pcreg: error: out of memory while pcreg loaded its modules (a memory limit "
                                       "such as ulimit -v below about 2 GB?)"]


@pytest.mark.parametrize("address, said", [
    ("notanaddress", "missing port"),
    ("foo://bar:1", "dask speaks .*tcp://.*, not foo://"),  # read "answered, but not as a dask scheduler"
    ("127.0.0.1:99999", "its port 99999 is not in 1-65535"),  # waited dask's connect time, 30 s
    ("tcp://127.0.0.1:0", "its port 0 is not in 1-65535"),
    ("tcp://:8786", "no host"),  # waited the connect time, then said the host was unreachable
    (":8786", "no host"),
])
def test_a_scheduler_address_that_cannot_be_one_is_refused_before_connecting(address, said):
    from pcreg._runner import make_executor
    from pcreg.errors import PcregError

    with pytest.raises(PcregError, match=f"^--scheduler '{re.escape(address)}' is not a dask scheduler address .*{said}") \
            as refused:
        with make_executor(scheduler=address):
            pass
    assert str(refused.value).count("is not a dask scheduler address") == 1


def test_too_many_workers_are_refused_saying_how_many_may_be_given():
    from pcreg._runner import make_executor
    from pcreg.errors import PcregError

    cpus = len(os.sched_getaffinity(0))
    with pytest.raises(PcregError, match=f"--workers {4 * cpus + 1} is more than 4x the {cpus} CPUs here: give "
                                         f"{4 * cpus} or fewer"):
        with make_executor(4 * cpus + 1):
            pass


def test_a_crosscheck_whose_reference_fails_says_why_on_stderr(tmp_path, capsys):
    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    cloud = np.random.default_rng(0).normal(size=(200, 3))
    np.save(a, cloud)
    np.save(b, cloud[0] + np.outer(np.arange(5), [0.002, 0.001, 0.0]))  # within reach, but on a line
    assert main(["crosscheck", str(a), str(b)]) == 3
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"reference ICP failed to register {b} onto {a}: " in err[0] and "collinear" in err[0]
    np.save(b, cloud[:2] + 0.01)  # two points within reach: refused before any ICP runs, in one line
    assert main(["crosscheck", str(a), str(b)]) == 3
    err = one_line_errors(capsys)
    assert len(err) == 1 and f"registration refused: {b}: 2 point(s) are too few for a rigid motion in 3-D (it needs 3)" in err[0]


@pytest.mark.parametrize("body, said", [("sys.exit(0)", "called sys.exit(0)"), ("raise SystemExit(3)", "called sys.exit(3)"),
                                        ("raise KeyboardInterrupt", "raised KeyboardInterrupt (no interrupt came)"),
                                        ("raise GeneratorExit", "raised GeneratorExit"),
                                        ("import os; os._exit(0)", "called os._exit(0)")])
def test_a_py_function_that_exits_or_raises_an_interrupt_fails_its_row_only(tmp_path, body, said):
    """sys.exit, os._exit or a KeyboardInterrupt in a py: function ended the cross-check (exit 0 with no output, exit
    3 with no message, or "interrupted"): now its row says so, and the others are reported."""
    import json

    a, b = tmp_path / "a.npy", tmp_path / "b.npy"
    pts = np.random.default_rng(0).uniform(-5, 5, (200, 3))
    np.save(a, pts)
    np.save(b, pts + 0.05)
    (tmp_path / "quitter.py").write_text(f"import sys\ndef icp(source, target, *, init, **params):\n    {body}\n")
    p = subprocess.run([sys.executable, "-m", "pcreg", "crosscheck", str(a), str(b), "--with",
                        "reference,py:quitter:icp,open3d", "--json"], capture_output=True, text=True, cwd=tmp_path,
                       timeout=300)
    assert p.returncode == 0, p.stderr
    rows = json.loads(p.stdout)["implementations"]
    assert said in rows["py:quitter:icp"]["error"] and rows["open3d"]["agrees"] is True, rows


def test_georeferenced_clouds_do_not_crash_the_probabilistic_libraries(tmp_path):
    """probreg's FilterReg on clouds 5e6 m from the origin (UTM coordinates) corrupted its memory and ended
    the process (exit 134, no row reported); the probabilistic libraries now work on centred clouds."""
    import json

    rng = np.random.default_rng(0)
    tgt = rng.uniform(-50, 50, (400, 3))
    c, s = np.cos(0.05), np.sin(0.05)
    src = (tgt - 0.3) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    offset = np.array([5e5, 5e6, 300.0])
    np.save(tmp_path / "t.npy", tgt + offset)
    np.save(tmp_path / "s.npy", src + offset)
    p = subprocess.run([sys.executable, "-m", "pcreg", "crosscheck", str(tmp_path / "t.npy"), str(tmp_path / "s.npy"),
                        "--with", "reference,probreg-filterreg,pycpd", "--json"], capture_output=True, text=True,
                       timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    rows = json.loads(p.stdout)["implementations"]
    assert rows["pycpd"]["agrees"] is True and rows["pycpd"]["translation_disagreement"] < 1e-3, rows["pycpd"]
    assert rows["probreg-filterreg"]["error"] is None and rows["probreg-filterreg"]["fitness"] > 0.9


@pytest.mark.skipif(sys.platform != "linux", reason="file names as bytes: a Linux file system")
def test_file_names_that_are_not_utf8_reach_suggest_and_are_refused_by_export(tmp_path):
    frames = os.fsdecode(bytes(tmp_path) + b"/fr\xffmes")
    os.mkdir(frames)
    rng = np.random.default_rng(0)
    scene = cv2.GaussianBlur(rng.integers(0, 256, (96, 140, 3), dtype=np.uint8), (0, 0), 1.5)
    for i in range(3):  # written by Python: OpenCV's own file functions crash on such a path
        with open(os.path.join(frames, f"f\udcfe{i}.png"), "wb") as fh:
            fh.write(cv2.imencode(".png", np.ascontiguousarray(scene[:, 10 - i:138 - i]))[1].tobytes())
    key = os.path.join(str(tmp_path), "key.png")
    cv2.imwrite(key, (np.arange(96)[:, None] * np.ones((1, 128)) > 48).astype(np.uint8))
    out = os.fsdecode(bytes(tmp_path) + b"/o\xffut")
    run = [sys.executable, "-m", "pcreg", "run", frames, "--labels", key, "--out", out, "--suggest", "1"]
    p = subprocess.run(run, capture_output=True)
    assert p.returncode == 0, p.stderr
    assert open(os.path.join(out, "suggest.txt"), "rb").read().startswith(b"f\xfe")  # the file's own bytes
    # a zip names its members in UTF-8: stored with U+FFFD, the masks matched no frame where they were imported
    p = subprocess.run([sys.executable, "-m", "pcreg", "export", out], capture_output=True)
    assert p.returncode == 2, p.stderr
    said = p.stderr.decode().splitlines()
    assert len(said) == 1 and "f\\udcfe0.png': a frame name that is not UTF-8" in said[0], said
    assert not os.path.exists(os.path.join(out, "export-cvat-mask.zip"))


def test_export_never_replaces_a_file_of_the_run_and_a_suite_that_is_a_file_is_refused_first(tmp_path, capsys):
    rng = np.random.default_rng(0)
    scene = cv2.GaussianBlur(rng.integers(0, 256, (96, 140, 3), dtype=np.uint8), (0, 0), 1.5)
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(3):
        cv2.imwrite(str(frames / f"f{i}.png"), np.ascontiguousarray(scene[:, 10 - i:138 - i]))
    cv2.imwrite(str(tmp_path / "key.png"), (np.arange(96)[:, None] * np.ones((1, 128)) > 48).astype(np.uint8))
    out = tmp_path / "out"
    assert main(["run", str(frames), "--labels", str(tmp_path / "key.png"), "--out", str(out)]) == 0
    before = (out / "f1.png").read_bytes()
    capsys.readouterr()
    assert main(["export", str(out), "--to", str(out / "f1.png"), "--force"]) == 2
    assert "would replace one of the run's files" in one_line_errors(capsys)[-1]
    assert (out / "f1.png").read_bytes() == before
    assert main(["export", str(out), "--to", str(out / "mine.zip")]) == 0  # a zip of its own there is fine
    other = tmp_path / "other" / "f0.png"  # another run's frame (a folder this run does not read): not over it either
    other.parent.mkdir()
    cv2.imwrite(str(other), scene)
    kept = other.read_bytes()
    assert main(["export", str(out), "--to", str(other), "--force"]) == 2
    assert one_line_errors(capsys)[-1] == (f"pcreg: error: --to {other}: not a .zip name; the archive CVAT imports is "
                                           "a .zip (name it NAME.zip)")
    assert other.read_bytes() == kept
    capsys.readouterr()
    assert main(["crosscheck", "--suite", str(out / "f1.png")]) == 2
    assert "exists and is not a folder" in one_line_errors(capsys)[-1]


def _jpeg_turned(img: np.ndarray) -> bytes:
    """A JPEG of ``img`` whose EXIF orientation (6) asks viewers to turn it a quarter clockwise."""
    import struct

    jpeg = cv2.imencode(".jpg", img)[1].tobytes()
    ifd = struct.pack(">H", 1) + struct.pack(">HHIHH", 0x0112, 3, 1, 6, 0) + struct.pack(">I", 0)
    exif = b"Exif\x00\x00" + b"MM\x00\x2a" + struct.pack(">I", 8) + ifd
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(exif) + 2) + exif + jpeg[2:]


def test_an_exif_orientation_is_never_applied_so_frames_and_labels_share_a_grid(tmp_path):
    from pcreg.datasets import load_dataset

    img = np.random.default_rng(0).integers(0, 256, (48, 80, 3), dtype=np.uint8)
    data = _jpeg_turned(img)
    probe = tmp_path / "probe.jpg"
    probe.write_bytes(data)
    assert cv2.imread(str(probe), cv2.IMREAD_COLOR).shape[:2] == (80, 48)  # OpenCV itself turns it
    clip = tmp_path / "clip"
    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    for i in range(2):
        (clip / "images" / f"f{i}.jpg").write_bytes(data)
        cv2.imwrite(str(clip / "labels" / f"f{i}.png"), np.zeros((48, 80), np.uint8))
    frames = load_dataset(f"folder:{clip}")["clip"]
    assert frames[0].image.shape == (48, 80, 3) and frames[0].labels.shape == (48, 80)


def test_labels_drawn_on_the_view_an_exif_orientation_shows_are_refused_saying_so(tmp_path, capsys):
    """A phone's portrait photograph is stored landscape with orientation 6: labels drawn on it as a viewer
    shows it are its size turned, which the refusal explains (pcreg reads the pixels as stored)."""
    from pcreg.errors import DatasetError
    from pcreg.datasets import load_dataset

    rng = np.random.default_rng(0)
    clip = tmp_path / "clip"
    (clip / "images").mkdir(parents=True)
    (clip / "labels").mkdir()
    for i in range(2):
        (clip / "images" / f"f{i}.jpg").write_bytes(_jpeg_turned(rng.integers(0, 256, (48, 80, 3), dtype=np.uint8)))
        cv2.imwrite(str(clip / "labels" / f"f{i}.png"), (np.arange(80 * 48).reshape(80, 48) % 2).astype(np.uint8))
    said = "f0.jpg's EXIF orientation 6 has viewers show it turned by a quarter; pcreg reads the pixels as stored"
    assert main(["run", str(clip / "images"), "--labels", str(clip / "labels" / "f0.png"), "--out", str(tmp_path / "o")]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and "labels are 48x80, the key frame f0.jpg is 80x48" in err[0] and said in err[0], err
    assert main(["run", str(clip / "images"), "--labels", str(clip / "labels"), "--out", str(tmp_path / "o")]) == 2
    assert said in one_line_errors(capsys)[0]
    with pytest.raises(DatasetError, match=said):
        load_dataset(f"folder:{clip}")
    cv2.imwrite(str(clip / "labels" / "f0.png"), np.zeros((40, 80), np.uint8))  # another size, not the turned one
    assert main(["run", str(clip / "images"), "--labels", str(clip / "labels" / "f0.png"), "--out", str(tmp_path / "o")]) == 2
    assert "EXIF" not in one_line_errors(capsys)[0]


def test_pcreg_register_says_when_a_photograph_is_shown_turned_by_its_exif_orientation(tmp_path, capsys):
    """A phone's photograph stored landscape with orientation 6 is registered as stored (T_ref_mov maps its
    stored pixels), and the command says so, naming the file; a JPEG without the tag gets no note."""
    import pcreg

    img = pcreg.synthetic("syn2a", n_frames=1)[0].image[:, :, ::-1]
    turned, plain = tmp_path / "phone shot.jpg", tmp_path / "plain.jpg"
    turned.write_bytes(_jpeg_turned(img))
    cv2.imwrite(str(plain), img)
    assert main(["register", str(plain), str(turned)]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if "EXIF" in line]
    assert notes == [f"pcreg: note: {turned}'s EXIF orientation 6 has viewers show it turned by a quarter; pcreg "
                     "registers the pixels as stored, and T_ref_mov maps them, not the view shown (turn the image "
                     "first to register the view: exiftran -ai for a JPEG, or Pillow's ImageOps.exif_transpose for "
                     "any format)"], notes
    assert main(["register", str(plain), str(turned), "--json"]) == 0  # and in --json's notes
    assert [n for n in json.loads(capsys.readouterr().out)["notes"] if "EXIF" in n] == [notes[0][len("pcreg: note: "):]]
    assert main(["register", str(plain), str(plain)]) == 0
    assert "EXIF" not in capsys.readouterr().err
    # pcreg crosscheck of the same photographs says it too (it said nothing), on stderr and in --json
    main(["crosscheck", str(plain), str(turned)])
    assert [line for line in capsys.readouterr().err.splitlines() if "EXIF" in line] == [
        notes[0].replace("pcreg registers", "pcreg cross-checks")]
    main(["crosscheck", str(plain), str(turned), "--json"])
    assert [n for n in json.loads(capsys.readouterr().out)["notes"] if "EXIF" in n] == [
        notes[0][len("pcreg: note: "):].replace("pcreg registers", "pcreg cross-checks")]
    main(["crosscheck", str(plain), str(plain)])
    assert "EXIF" not in capsys.readouterr().err


def test_the_exif_note_reads_headers_alone_and_passes_images_over_pillows_own_limit(tmp_path, monkeypatch, capsys):
    """The orientation is read from the header: a PNG's eXIf chunk before its pixels is found, a PNG without
    one is not decoded by Pillow to look for one after them, and an image over Pillow's own pixel limit
    (DecompressionBombError; pcreg's limit is checked on reading) gets no note rather than an internal error."""
    import PIL.Image

    import pcreg
    from pcreg.formats import exif_orientation

    img = pcreg.synthetic("syn2a", n_frames=1)[0].image
    exif = PIL.Image.Exif()
    exif[0x0112] = 6
    shown, plain = tmp_path / "shown.png", tmp_path / "plain.png"
    PIL.Image.fromarray(img).save(shown, exif=exif)
    PIL.Image.fromarray(img).save(plain)
    assert exif_orientation(shown) == 6 and exif_orientation(plain) is None
    turned = tmp_path / "turned.jpg"
    turned.write_bytes(_jpeg_turned(img[:, :, ::-1]))
    monkeypatch.setattr(PIL.Image, "MAX_IMAGE_PIXELS", img.shape[0] * img.shape[1] // 4)
    assert main(["register", str(plain), str(turned)]) == 0
    assert "EXIF" not in capsys.readouterr().err


@pytest.mark.parametrize("app1", [b"Exif\x00\x00MM\x00\x2a\xff\xff\xff\x00",  # the first IFD past the end
                                  b"Exif\x00\x00MM\x00\x2a\x00\x00\x00\x08\xff\xff"])  # 65535 entries, none there
def test_a_jpeg_with_damaged_exif_registers_without_pillows_warning(tmp_path, capsys, recwarn, app1):
    """A JPEG whose EXIF block is damaged registers as any JPEG: Pillow's "Corrupt EXIF data" warning, which
    names no file, is not shown (it was, with the line of Pillow's source that raised it)."""
    import struct

    import pcreg

    img = pcreg.synthetic("syn2a", n_frames=1)[0].image[:, :, ::-1]
    plain, damaged = tmp_path / "plain.png", tmp_path / "damaged exif.jpg"
    cv2.imwrite(str(plain), img)
    jpeg = cv2.imencode(".jpg", img)[1].tobytes()
    damaged.write_bytes(jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + jpeg[2:])
    assert main(["register", str(plain), str(damaged)]) == 0
    assert "EXIF" not in capsys.readouterr().err
    assert [str(w.message) for w in recwarn] == []


def test_an_initial_guess_far_off_is_refused_for_no_overlap_not_as_a_horizon(tmp_path, capsys):
    """--init of a translation of 1e12 pixels (the largest entry an initial guess may hold) overlaps nothing, and
    is refused saying so, as one of 5000 pixels is (it read "sends part of the image through infinity")."""
    import pcreg

    img = tmp_path / "a.png"
    cv2.imwrite(str(img), pcreg.synthetic("syn2a", n_frames=1)[0].image[:, :, ::-1])
    for shift in ("5000", "1e12"):
        (tmp_path / "init.txt").write_text(f"1 0 {shift}\n0 1 0\n0 0 1\n")
        assert main(["register", str(img), str(img), "--init", str(tmp_path / "init.txt"), "--model", "translation"]) == 3
        assert "no overlap" in one_line_errors(capsys)[0]


@pytest.mark.parametrize("dtype", [np.int16, np.int32])
def test_a_signed_or_32_bit_tiff_is_refused_saying_what_pcreg_reads(tmp_path, capsys, dtype):
    """A scientific camera's signed 16-bit TIFF, or Pillow's 32-bit integer mode "I": exit 2, one line that
    names the file and the kinds of image pcreg reads."""
    ref, mov = tmp_path / "ref.png", tmp_path / "signed.tif"
    cv2.imwrite(str(ref), np.zeros((64, 64), np.uint8))
    assert cv2.imwrite(str(mov), (np.arange(64 * 64).reshape(64, 64) - 2000).astype(dtype))
    assert main(["register", str(ref), str(mov)]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and err[0].startswith(f"pcreg: error: {mov}: unsupported image dtype "), err
    assert "pcreg reads 8- and 16-bit unsigned integers, true/false, and floats in [0, 1]" in err[0]


def test_pcreg_register_says_when_a_jpeg_decoded_around_damaged_data(tmp_path, capsys):
    """Bytes changed in a JPEG's scan: libjpeg decodes around them ("Corrupt JPEG data: ...") and returns an
    image whose pixels after the damage are its guesses; the registration is returned, and marked."""
    import pcreg

    img = pcreg.synthetic("syn2a", n_frames=1)[0].image[:, :, ::-1]
    intact = cv2.imencode(".jpg", img)[1].tobytes()
    damaged = bytearray(intact)
    middle = len(damaged) // 2
    damaged[middle:middle + 64] = bytes(range(64))
    ref, good, bad = tmp_path / "ref.png", tmp_path / "good.jpg", tmp_path / "bad.jpg"
    cv2.imwrite(str(ref), img)
    good.write_bytes(intact)
    bad.write_bytes(bytes(damaged))
    assert cv2.imread(str(bad)) is not None  # OpenCV returns it as an image
    assert main(["register", str(ref), str(bad)]) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if "damaged" in line]
    assert len(notes) == 1 and notes[0].startswith(f"pcreg: note: {bad}: its decoder reports damaged data (Corrupt "
                                                   "JPEG data: "), notes
    assert notes[0].endswith("part of the image is the decoder's guess, and the result may be off")
    assert main(["register", str(ref), str(good)]) == 0
    assert "damaged" not in capsys.readouterr().err
    # pcreg crosscheck of the same images says it too (it said nothing), on stderr and in --json
    assert main(["crosscheck", str(ref), str(bad)]) == 0
    assert [line for line in capsys.readouterr().err.splitlines() if "damaged" in line] == notes
    assert main(["crosscheck", str(ref), str(bad), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["notes"] == [notes[0].removeprefix("pcreg: note: ")]


def test_a_signal_while_the_commands_load_is_an_interruption(monkeypatch, capsys):
    """Ctrl-C or SIGTERM (made a KeyboardInterrupt from the start of main) while the commands' modules load."""
    import signal

    import pcreg.cli as cli

    def loading():
        raise KeyboardInterrupt

    before = signal.getsignal(signal.SIGTERM)
    monkeypatch.setattr(cli, "build_parser", loading)
    assert cli.main(["register", "a.png", "b.png"]) == 130
    assert one_line_errors(capsys) == ["pcreg: interrupted before the command started"]
    assert signal.getsignal(signal.SIGTERM) is before  # the handlers put back


def test_viewing_a_run_folder_whose_run_json_is_damaged_names_the_run_json(tmp_path, capsys):
    (tmp_path / "run.json").write_text("garbage")
    assert main(["view", str(tmp_path), "--web"]) == 2
    assert one_line_errors(capsys)[-1].endswith("run.json: unreadable (not a run.json that pcreg run wrote)")


@pytest.mark.parametrize("size", ["16384x16384", "8193x100", "15x900", "wide"])
def test_a_screenshot_size_the_headless_viewer_cannot_draw_is_refused_at_once(tmp_path, capsys, size):
    with pytest.raises(SystemExit, match="2"):
        main(["view", str(tmp_path / "r.rrd"), "--screenshot", str(tmp_path / "s.png"), "--size", size])
    assert "--size" in capsys.readouterr().err


def test_a_stop_that_does_not_end_by_itself_is_ended_after_its_grace(tmp_path):
    """Wherever the signal lands, a stopping command ends: past the grace from the first signal, the
    watchdog ends the process with exit 130; a command that ends by itself puts the watchdog away."""
    import textwrap
    import threading

    script = tmp_path / "stuck.py"
    script.write_text(textwrap.dedent("""
        import os, signal, threading
        from pcreg import _runner, _signals
        _signals.STOP_GRACE_SECONDS = 0.5  # read where the watchdog lives
        _runner.interrupt_on_signals()
        try:
            os.kill(os.getpid(), signal.SIGTERM)  # handled at once: a KeyboardInterrupt here
        except KeyboardInterrupt:
            pass
        never = threading.Event()
        while True:  # a stop that never ends by itself: the interruption is swallowed, the wait goes on
            try:
                never.wait()
            except KeyboardInterrupt:
                pass
    """))
    p = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert p.returncode == 130 and "still stopping after 0.5 s, so ended now (what was finished is kept)" in p.stderr

    from pcreg import _runner

    previous = _runner.interrupt_on_signals()
    try:
        _runner._on_signal(15, None)
    except KeyboardInterrupt:
        pass
    watchdog = next(t for t in threading.enumerate() if t.name == "pcreg-stop-watchdog")
    _runner.restore_signals(previous)  # the command ended by itself: the watchdog stands down
    watchdog.join(timeout=120)
    assert not watchdog.is_alive() and not _runner._WATCHDOG


def test_the_signal_handler_starts_no_thread():
    """A signal lands wherever the main thread is, even inside ``threading``'s bookkeeping of a thread being
    started (where starting another one in the handler broke that bookkeeping: a KeyError from
    ``del _limbo[self]``): the watchdog runs before any signal, and the handler only arms it."""
    import threading

    from pcreg import _runner

    previous = _runner.interrupt_on_signals()
    try:
        before = {t.ident for t in threading.enumerate()}
        assert any(t.name == "pcreg-stop-watchdog" for t in threading.enumerate())
        with pytest.raises(KeyboardInterrupt):
            _runner._on_signal(2, None)
        assert {t.ident for t in threading.enumerate()} <= before
    finally:
        _runner.restore_signals(previous)


def test_a_signal_landing_where_python_cannot_raise_is_noted_not_printed(tmp_path):
    """A signal landing in a callback the garbage collector runs (matplotlib's, as a report's figures are
    written) raised a KeyboardInterrupt that Python could only print: "Exception ignored in" and a traceback
    beside the command's one line. It is noted, and raised again at the next check."""
    import textwrap

    script = tmp_path / "callback.py"
    script.write_text(textwrap.dedent("""
        import signal, weakref
        from pcreg import _runner
        _runner.interrupt_on_signals()
        class Node:
            pass
        node = Node()
        ref = weakref.ref(node, lambda _: signal.getsignal(signal.SIGINT)(signal.SIGINT, None))
        del node  # the callback runs now, and the signal's handler in it
        try:
            _runner.check_interrupted()
        except KeyboardInterrupt:
            print("raised again")
    """))
    p = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert (p.returncode, p.stdout, p.stderr) == (0, "raised again\n", "")


def test_a_command_stopped_by_bad_input_leaves_no_folder_it_made(tmp_path, capsys):
    out = tmp_path / "made" / "for" / "it"
    assert main(["evaluate", "stream", "--out", str(out), "--data", f"camvid:{tmp_path / 'none'}"]) == 2
    assert "no such folder" in capsys.readouterr().err
    assert not (tmp_path / "made").exists()  # the folder and the parents the lock made, gone again
    kept = tmp_path / "kept"
    kept.mkdir()
    assert main(["evaluate", "stream", "--out", str(kept), "--data", f"camvid:{tmp_path / 'none'}"]) == 2
    assert kept.is_dir()  # a folder that was there before stays


@pytest.mark.parametrize("command", [["evaluate", "stream"], ["evaluate", "classification"], ["evaluate", "sequence"]])
def test_an_evaluation_never_writes_into_its_own_data_folder(tmp_path, capsys, command):
    """``--out`` inside ``--data``: the report's stream.png replaced a frame of that name, and the next run read
    the report's files as frames or labels."""
    (tmp_path / "clip" / "images").mkdir(parents=True)
    (tmp_path / "clip" / "images" / "stream.png").write_bytes(b"a frame")
    assert main([*command, "--data", f"camvid:{tmp_path}", "--out", str(tmp_path / "clip" / "images")]) == 2
    assert "inside the data folder" in capsys.readouterr().err
    assert (tmp_path / "clip" / "images" / "stream.png").read_bytes() == b"a frame"
    # a kind pcreg does not read is said as such, not as an --out inside its folder
    assert main([*command, "--data", f"foo:{tmp_path}", "--out", str(tmp_path / "clip" / "images")]) == 2
    assert "unknown kind 'foo'" in capsys.readouterr().err


def test_an_interrupted_evaluation_with_a_recording_says_to_resume_with_another(tmp_path, monkeypatch, capsys):
    """"rerun the same command to resume" was refused: the recording exists; with another --record file the
    finished units are kept."""
    import pcreg.experiments.sequence

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(pcreg.experiments.sequence, "evaluate", stopped)
    assert main(["evaluate", "sequence", "--frames", "4", "--size", "160x120", "--out", str(tmp_path / "o"),
                 "--record", str(tmp_path / "o" / "a.rrd")]) == 130
    assert "rerun the same command with another --record file" in capsys.readouterr().err


def test_an_interrupted_command_with_nothing_to_resume_says_only_that_it_was_interrupted(tmp_path, monkeypatch, capsys):
    """``register`` (and ``crosscheck``, ``demo``, or any command stopped before its arguments were read) said
    "finished units are kept; rerun the same command to resume", the evaluations' words: nothing of it resumes."""
    import pcreg.registration.api

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(pcreg.registration.api, "register", stopped)
    image = np.zeros((64, 64, 3), np.uint8)
    image[16:48, 16:48] = 255
    for name in ("a.png", "b.png"):
        cv2.imwrite(str(tmp_path / name), image)
    assert main(["register", str(tmp_path / "a.png"), str(tmp_path / "b.png")]) == 130
    assert capsys.readouterr().err == "pcreg: interrupted\n"


def test_a_float_tiff_outside_0_1_is_refused_saying_what_to_save_it_as_not_to_divide(tmp_path, capsys):
    """A float TIFF of 8-bit values (0..255): a command-line user cannot divide an array by 255; the line says
    what file pcreg reads instead."""
    ref, mov = tmp_path / "ref.png", tmp_path / "float.tif"
    cv2.imwrite(str(ref), np.zeros((64, 64), np.uint8))
    assert cv2.imwrite(str(mov), np.random.default_rng(0).uniform(0, 255, (64, 64)).astype(np.float32))
    assert main(["register", str(ref), str(mov)]) == 2
    err = one_line_errors(capsys)
    assert len(err) == 1 and err[0].startswith(f"pcreg: error: {mov}: a float image must hold values in [0, 1]"), err
    assert "divide" not in err[0] and "save it as an 8- or 16-bit unsigned integer image" in err[0], err


def test_a_correspondence_distance_too_small_to_match_is_named_not_called_no_overlap(tmp_path, capsys):
    """An image against itself with ``--max-distance 1e-300``: refused as "no overlap between the images: 2000 of 2000
    moving edge points land on the reference", which contradicts itself; the refusal names the distance."""
    import pcreg

    path = tmp_path / "frame.png"
    cv2.imwrite(str(path), pcreg.synthetic("syn2a", n_frames=1)[0].image[:, :, ::-1])
    assert main(["register", str(path), str(path), "--max-distance", "1e-300"]) == 3
    err = one_line_errors(capsys)
    assert len(err) == 1 and "no overlap" not in err[0], err
    assert "no moving edge point came within the correspondence distance of a reference edge point" in err[0]
    assert err[0].endswith("the images do not match there, or the distance is too small (--max-distance, "
                           "max_correspondence_distance)")



@pytest.mark.parametrize("given, on", [("0", False), ("false", False), ("OFF", False), (" no ", False), ("1", True),
                                       ("true", True), ("Yes", True), ("", True), (None, True), ("maybe", None),
                                       ("2", None), ("-1", None)])
def test_helper_thread_values_are_read_as_said_and_others_refused(given, on, monkeypatch, capsys):
    """PCREG_HELPER_THREAD turned the helper off at 0 alone: `false` or `off` left it on without a word. The words of
    off and on are read; any other value is refused before the command starts, in one line."""
    from pcreg._threads import wanted

    assert wanted(given) is on
    if given is None:
        monkeypatch.delenv("PCREG_HELPER_THREAD", raising=False)
    else:
        monkeypatch.setenv("PCREG_HELPER_THREAD", given)
    if on is None:
        assert main(["--version"]) == 2
        assert one_line_errors(capsys) == [f"pcreg: error: PCREG_HELPER_THREAD={given!r}: 0 or false or off or no turns "
                                           "the helper thread off, 1 or true or on or yes (or unset) leaves it on"]
    else:
        with pytest.raises(SystemExit) as done:
            main(["--version"])
        assert done.value.code == 0 and one_line_errors(capsys) == []
