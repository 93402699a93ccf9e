"""The `pcreg register` and `pcreg crosscheck` commands, end to end, through the console script."""

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

import pcreg
from pcreg import transforms as tf

from _images import moved, rigid_about_centre, shapes_image

PCREG = [sys.executable, "-m", "pcreg.cli"]


def run(*args, cwd=None):
    return subprocess.run([*PCREG, *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=300)


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    d = tmp_path_factory.mktemp("pair")
    ref = shapes_image()
    T = rigid_about_centre(ref.shape, 60.0, 15.0, -10.0)
    cv2.imwrite(str(d / "ref.png"), ref[:, :, ::-1])
    cv2.imwrite(str(d / "mov.png"), moved(ref, T)[:, :, ::-1])
    return d, T


def test_register_json_and_warped_output(pair, tmp_path):
    d, T = pair
    out = tmp_path / "warped.png"
    p = run("register", d / "ref.png", d / "mov.png", "--json", "--out", out)
    assert p.returncode == 0, p.stderr
    result = json.loads(p.stdout)
    assert set(result) == {"ok", "matrix", "fitness", "inlier_rmse", "iterations", "converged", "backend", "seconds",
                           "inlier_ratio", "chance_ratio", "overlap", "generator", "frames", "model_fit", "settling", "trusted", "notes"}
    assert result["settling"]["shift_px"] == 0.0 and result["settling"]["taken"] is False  # refined again, it came back
    assert result["notes"] == [] and "note" not in p.stderr  # a plain photograph's rigid view: nothing to say
    assert result["frames"] == "T_ref_mov"  # the name of ``matrix``: moving image -> reference image
    assert result["model_fit"]["model"] == "projective" and result["model_fit"]["fits"] is True  # a rigid view
    assert "features" not in result  # a rigid result: the model check's (the features check a projective one)
    assert result["ok"] is True and result["inlier_ratio"] > 0.5
    assert tf.max_corner_error(np.array(result["matrix"]), T, (240, 320)) < 0.5
    assert result["seconds"] > 0 and result["backend"] == "reference"
    assert cv2.imread(str(out)).shape == (240, 320, 3)
    # a register killed while it wrote --out left its temporary file beside it for ever: removed by the next write
    killed = tmp_path / ".warped.png.k1ll3d00.tmp"
    killed.write_bytes(b"half a PNG")
    assert run("register", d / "ref.png", d / "mov.png", "--out", out, "--force").returncode == 0
    assert not killed.exists() and cv2.imread(str(out)).shape == (240, 320, 3)



def test_register_starts_from_a_prior_pose_given_as_a_file(pair, tmp_path):
    """``--init FILE``: a 3x3 T_ref_mov (odometry's prior, a degree and a few px off) is refined instead of searched
    from (the library's ``init=``, which the command could not pass); the view turned 60 degrees is registered from
    it, where ``--init identity`` is refused. A file that is no 3x3 transform is refused naming it, exit 2."""
    d, T = pair
    off = rigid_about_centre((240, 320), 1.0, 3.0, -2.0)
    np.savetxt(tmp_path / "prior.txt", off @ T)
    p = run("register", d / "ref.png", d / "mov.png", "--json", "--init", tmp_path / "prior.txt")
    assert p.returncode == 0, p.stderr
    result = json.loads(p.stdout)
    assert result["generator"] == "init" and tf.max_corner_error(np.array(result["matrix"]), T, (240, 320)) < 0.5
    assert run("register", d / "ref.png", d / "mov.png", "--init", "identity").returncode == 3
    np.savetxt(tmp_path / "cloud_pose.txt", np.eye(4))
    p = run("register", d / "ref.png", d / "mov.png", "--init", tmp_path / "cloud_pose.txt")
    assert p.returncode == 2 and p.stderr.strip().splitlines() == [
        f"pcreg: error: {tmp_path / 'cloud_pose.txt'}: the initial guess must be a finite 3x3 matrix, got shape (4, 4)"]


def test_register_takes_global_as_the_library_does_for_auto(pair):
    """``--init global``, the library's other name of ``auto`` (``RegisterConfig.init``), is the global search, not a
    file named "global" (refused as "global: no such file")."""
    from pcreg.cli import main

    d, T = pair
    assert main(["register", str(d / "ref.png"), str(d / "mov.png"), "--init", "global", "--json"]) == 0

def test_register_says_the_motion_and_its_evidence_in_a_line(pair):
    """Beside the result, one line a person reads: the rotation and shift of the transform printed, and the share of
    edge points that line up against chance's."""
    import re

    d, T = pair
    p = run("register", d / "ref.png", d / "mov.png")
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    assert len(lines) == 2 and lines[0].startswith("RegistrationResult(")
    said = re.fullmatch(r"rigid motion: rotation (\S+) deg, shift \((\S+), (\S+)\) px; (\S+)% of the moving edge points "
                        r"line up with the reference's, (\S+)x the (\S+)% unrelated content would give \(refused under 2x\)",
                        lines[1])
    assert said is not None, lines[1]
    angle, x, y, share, times, chance = map(float, said.groups())
    assert abs(angle - np.degrees(np.arctan2(T[1, 0], T[0, 0]))) < 0.1
    assert abs(x - T[0, 2]) < 0.5 and abs(y - T[1, 2]) < 0.5
    assert share > 50 and abs(times - share / chance) < 0.1


def test_the_evidence_line_names_no_refusal_when_the_test_is_off(pair):
    """With ``--min-inlier-ratio 0`` nothing is refused, so the line says the test is off instead of the
    factor under which a registration would have been refused."""
    d, _ = pair
    p = run("register", d / "ref.png", d / "mov.png", "--min-inlier-ratio", "0")
    assert p.returncode == 0, p.stderr
    said = p.stdout.splitlines()[1]
    assert "refused under" not in said and said.endswith("(no plausibility test: --min-inlier-ratio 0)"), said


def test_warped_output_keeps_the_moving_files_depth_and_channels(pair, tmp_path):
    """A 16-bit grey moving image is written warped as 16-bit grey, an RGBA one keeps its alpha (transparent
    outside the moving image): both were written as 8-bit RGB."""
    d, T = pair
    grey = cv2.cvtColor(cv2.imread(str(d / "mov.png")), cv2.COLOR_BGR2GRAY)
    cv2.imwrite(str(tmp_path / "mov16.png"), grey.astype(np.uint16) * 257)
    cv2.imwrite(str(tmp_path / "mova.png"), cv2.cvtColor(cv2.imread(str(d / "mov.png")), cv2.COLOR_BGR2BGRA))
    expected = cv2.imread(str(d / "ref.png"), cv2.IMREAD_GRAYSCALE).astype(float) * 257
    for name in ("mov16", "mova"):
        p = run("register", d / "ref.png", tmp_path / f"{name}.png", "--out", tmp_path / f"{name}_w.png")
        assert p.returncode == 0, p.stderr
    w16 = cv2.imread(str(tmp_path / "mov16_w.png"), cv2.IMREAD_UNCHANGED)
    assert w16.dtype == np.uint16 and w16.shape == (240, 320)
    inside = cv2.erode((w16 > 0).astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    assert np.median(np.abs(w16[inside] - expected[inside])) < 3 * 257  # the reference, in 16-bit units
    wa = cv2.imread(str(tmp_path / "mova_w.png"), cv2.IMREAD_UNCHANGED)
    assert wa.shape == (240, 320, 4) and wa[..., 3].min() == 0 and wa[..., 3].max() == 255


def test_register_never_writes_over_its_inputs_even_with_force(pair, tmp_path):
    d, _ = pair
    ref, mov = tmp_path / "ref.png", tmp_path / "mov.png"
    ref.write_bytes((d / "ref.png").read_bytes())
    mov.write_bytes((d / "mov.png").read_bytes())
    (tmp_path / "link.png").symlink_to(ref)
    before = ref.read_bytes(), mov.read_bytes()
    for out in (ref, mov, tmp_path / "link.png"):
        p = run("register", ref, mov, "--out", out, "--force")
        assert p.returncode == 2 and "the output would overwrite it" in p.stderr, p.stderr
    assert (ref.read_bytes(), mov.read_bytes()) == before


def test_register_given_point_clouds_says_which_command_registers_them(pair, tmp_path, capsys):
    """A first try with another project's test clouds (PCL's test/bun4.pcd test/bun0.pcd): register said
    'not an image pcreg reads (PNG, JPEG, ...)' and no more."""
    from pcreg.cli import main

    d, _ = pair
    np.save(tmp_path / "target.npy", np.random.default_rng(0).normal(size=(50, 3)))
    for first, second in ((tmp_path / "target.npy", tmp_path / "bun0.pcd"), (d / "ref.png", tmp_path / "fish.TXT")):
        assert main(["register", str(first), str(second), "--json"]) == 2
        out, err = capsys.readouterr()
        cloud = first if first.suffix == ".npy" else second
        assert err == (f"pcreg: error: {cloud}: a point cloud; pcreg register takes two images. Register two clouds "
                       "with pcreg crosscheck TARGET SOURCE (its reference row is pcreg's ICP) or pcreg.icp\n")
        assert out == ""


def test_transparent_pixels_are_not_registered(tmp_path):
    """Two RGBA images whose visible parts are one scene shifted by (-20, 15) and whose transparent parts
    hold one same picture: the transparent parts aligned (a shift of 0, exit 0); a viewer shows nothing
    there, and nothing there is matched now."""
    from pcreg.datasets.textures import texture

    scene = texture("leaves", height=240, width=320)
    h, w = scene.shape[:2]
    T = np.array([[1.0, 0, -20], [0, 1, 15], [0, 0, 1]])
    shifted = moved(scene, T)
    hidden = texture("leaves", height=h, width=w // 2, seed=1)  # half of each image, the same in both
    for name, img in (("a.png", scene), ("b.png", shifted)):
        rgba = np.dstack([img[:, :, ::-1], np.full((h, w), 255, np.uint8)])
        rgba[:, : w // 2, :3], rgba[:, : w // 2, 3] = hidden[:, :, ::-1], 0
        cv2.imwrite(str(tmp_path / name), rgba)
    p = run("register", tmp_path / "a.png", tmp_path / "b.png", "--json")
    assert p.returncode == 0, p.stderr
    assert tf.max_corner_error(np.array(json.loads(p.stdout)["matrix"]), T, (h, w)) < 1.0
    p = run("register", tmp_path / "a.png", tmp_path / "b.png", "--model", "dense")  # it cannot leave them out
    assert p.returncode == 2 and p.stderr.startswith(f"pcreg: error: {tmp_path / 'a.png'}: transparent pixels"), p.stderr
    with pytest.raises(pcreg.errors.InputError, match="cannot leave masked pixels out"):
        pcreg.register(scene, shifted, model="dense", moving_mask=np.ones((h, w), bool))
    cv2.imwrite(str(tmp_path / "whole.png"), scene[:, :, ::-1])
    cv2.imwrite(str(tmp_path / "small.png"), cv2.resize(scene, (w // 2, h // 2)))
    p = run("register", tmp_path / "whole.png", tmp_path / "small.png", "--model", "dense")
    assert p.returncode == 2 and p.stderr.startswith(f"pcreg: error: {tmp_path / 'small.png'}: {w // 2}x{h // 2} px"), p.stderr


def test_an_image_transparent_everywhere_is_bad_input_naming_its_file(pair, tmp_path):
    """A PNG whose alpha is 0 everywhere shows nothing: refused as bad input naming the file (exit 2), as
    either image; it was a refused registration (exit 3, "no usable edges") that named neither. Read as an
    image (``pcreg.load_image``) it keeps its colours, alpha dropped."""
    d, _ = pair
    ref = cv2.imread(str(d / "ref.png"))
    cv2.imwrite(str(tmp_path / "clear.png"), np.dstack([ref, np.zeros(ref.shape[:2], np.uint8)]))
    for args in ((d / "ref.png", tmp_path / "clear.png"), (tmp_path / "clear.png", d / "mov.png")):
        p = run("register", *args)
        assert p.returncode == 2 and p.stderr.splitlines() == [
            f"pcreg: error: {tmp_path / 'clear.png'}: every pixel is transparent (alpha 0 everywhere): nothing to "
            "register"], p.stderr
    with pytest.warns(pcreg.errors.ImageWarning, match=r"clear\.png: 100% of its pixels are transparent \(alpha 0\)"):
        np.testing.assert_array_equal(pcreg.load_image(tmp_path / "clear.png"), ref[:, :, ::-1])


def test_an_image_whose_black_half_is_read_as_padding_is_refused_saying_so(pair, tmp_path):
    """A picture half pure black (touching its border), half grey: the black half is read as padding from a warp and
    left out, and the refusal said "no usable edges (a flat or empty image?)" of an image with a clear edge."""
    d, _ = pair
    step = np.zeros((120, 160, 3), np.uint8)
    step[:, 80:] = 200
    cv2.imwrite(str(tmp_path / "step.png"), step)
    p = run("register", d / "ref.png", tmp_path / "step.png")
    assert p.returncode == 3 and p.stderr.splitlines() == [
        f"pcreg: registration refused: {tmp_path / 'step.png'}: the moving image has no usable edges: 50% of it is left "
        "out (pure black touching its border is read as padding from a warp, a transparent pixel as no picture), and "
        "the rest holds none (pcreg.register's moving_mask=None keeps every pixel)"], p.stderr


def test_a_16_bit_image_of_8_bit_values_is_refused_saying_so(pair, tmp_path):
    """A 16-bit PNG whose values lie in 0..255 reads nearly black (16 bits are scaled by 1/257, as documented):
    its refusal names the file and says its values use only the lowest 8 of its 16 bits, with their range
    (it said "no usable edges (a flat or empty image?)", naming neither). A flat 8-bit image is still "flat or
    empty", now named by its file."""
    d, _ = pair
    ref = cv2.imread(str(d / "ref.png"))
    cv2.imwrite(str(tmp_path / "low.png"), ref.astype(np.uint16))
    said = (f"{tmp_path / 'low.png'}: the {{}} image has no usable edges: its 16-bit values lie in {ref.min()}..{ref.max()}, "
            "only the lowest 8 of its 16 bits, which read as 0..1 of 255 (nearly black); stretch them over the 16 bits "
            "or store the image as 8-bit")
    for args, role in (((d / "ref.png", tmp_path / "low.png"), "moving"), ((tmp_path / "low.png", d / "mov.png"), "reference")):
        p = run("register", *args, "--json")
        assert p.returncode == 3 and p.stderr.splitlines() == [f"pcreg: registration refused: {said.format(role)}"], p.stderr
        assert json.loads(p.stdout) == {"ok": False, "reason": said.format(role), "notes": []}
    cv2.imwrite(str(tmp_path / "flat.png"), np.full(ref.shape, 77, np.uint8))
    p = run("register", d / "ref.png", tmp_path / "flat.png")
    assert p.returncode == 3 and p.stderr.splitlines() == [
        f"pcreg: registration refused: {tmp_path / 'flat.png'}: the moving image has no usable edges (a flat or empty "
        "image?)"], p.stderr
    with pytest.raises(pcreg.errors.RegistrationError, match=r"^the moving image has no usable edges: its 16-bit values "
                       r"lie in \d+\.\.\d+, only the lowest 8 of its 16 bits"):
        pcreg.register(ref[:, :, ::-1], ref[:, :, ::-1].astype(np.uint16))


def test_a_16_bit_image_read_nearly_black_is_said_first_in_any_refusal_and_noted_on_a_result(tmp_path):
    """A grey 16-bit pair using the lowest 10 bits (0..738 of 65535, read as 0..3 of 255) is refused as unrelated: the
    refusal says first that the images read nearly black (it advised --min-inlier-ratio 0 alone, whose result on
    such images was hundreds of px off); a pair that registers notes it, and --json's reason is the whole refusal."""
    base = pcreg.synthetic("syn2a", n_frames=1)[0].image
    T = tf.about_point(tf.rigid2d(-20.0, 15.0, 8.0), tf.image_center(base.shape))
    moved, _ = pcreg.warp(base, np.linalg.inv(T))
    paths = {}
    for k in (3, 4):
        for name, img in (("ref", base), ("mov", moved)):
            paths[k, name] = tmp_path / f"x{k}_{name}.png"
            cv2.imwrite(str(paths[k, name]), cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.uint16) * k)
    p = run("register", paths[3, "ref"], paths[3, "mov"], "--json")
    assert p.returncode == 3, p.stderr
    reason = json.loads(p.stdout)["reason"]
    assert reason.startswith(f"registration refused: {paths[3, 'ref']} and {paths[3, 'mov']} read nearly black (16-bit "
                             "values in the lowest bits: stretch them over the 16 bits or store the image as 8-bit); "), reason
    assert p.stderr == f"pcreg: registration refused: {reason.removeprefix('registration refused: ')}\n"
    long = tmp_path / ("a" * 200) / ("b" * 200)  # a refusal longer than 1,000 characters: stderr's line is cut, not the JSON's
    long.mkdir(parents=True)
    for name in ("ref", "mov"):
        paths[3, name].rename(long / paths[3, name].name)
    p = run("register", long / paths[3, "ref"].name, long / paths[3, "mov"].name, "--json")
    reason = json.loads(p.stdout)["reason"]
    assert p.returncode == 3 and len(reason) > 1000 and not reason.endswith("...") and p.stderr.endswith("...\n")
    assert len(p.stderr) == len("pcreg: registration refused: ") + 1000 - len("registration refused: ") + 1
    p = run("register", paths[4, "ref"], paths[4, "mov"], "--json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert tf.max_corner_error(np.array(out["matrix"]), T, base.shape) < 0.5
    assert [n.split(": its")[0] for n in out["notes"]] == [str(paths[4, "ref"]), str(paths[4, "mov"])], out["notes"]


def test_an_image_too_small_for_the_pyramid_is_named_by_its_file(pair, tmp_path):
    d, _ = pair
    cv2.imwrite(str(tmp_path / "tiny.png"), np.full((16, 16, 3), 128, np.uint8))
    for args, role in (((d / "ref.png", tmp_path / "tiny.png"), "moving"), ((tmp_path / "tiny.png", d / "ref.png"), "reference")):
        p = run("register", *args)
        assert p.returncode == 2 and p.stderr.startswith(f"pcreg: error: {tmp_path / 'tiny.png'}: the {role} image (16x16)"), p.stderr


@pytest.mark.slow
def test_refused_registration_exits_3_with_one_line(pair, tmp_path):
    d, _ = pair
    noise = np.random.default_rng(0).integers(0, 256, (240, 320, 3), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "noise.png"), noise)
    p = run("register", d / "ref.png", tmp_path / "noise.png")
    assert p.returncode == 3, p.stderr
    assert p.stdout == "" and len(p.stderr.strip().splitlines()) == 1
    assert p.stderr.startswith("pcreg: registration refused: ")
    assert "refused: registration refused" not in p.stderr  # said once
    p = run("register", d / "ref.png", tmp_path / "noise.png", "--json")
    assert p.returncode == 3 and len(p.stderr.strip().splitlines()) == 1
    out = json.loads(p.stdout)
    assert out["ok"] is False and "refused" in out["reason"] and "\n" not in out["reason"]
    # The user's own threshold: 0 turns the test off.
    p = run("register", d / "ref.png", tmp_path / "noise.png", "--json", "--min-inlier-ratio", "0")
    assert p.returncode == 0 and json.loads(p.stdout)["ok"] is True


def test_open3d_refuses_the_point_to_line_finish_with_exit_2(pair):
    d, _ = pair
    p = run("register", d / "ref.png", d / "mov.png", "--backend", "open3d", "--refine", "point_to_line")
    assert p.returncode == 2 and "reference-backend finish" in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1
    # its advice is in the command's options (not the library's refine='none'), and followed it registers
    assert "leave --refine out with --backend open3d, or give --backend reference" in p.stderr, p.stderr
    p = run("register", d / "ref.png", d / "mov.png", "--backend", "reference", "--refine", "point_to_line")
    assert p.returncode == 0, p.stderr


def test_register_open3d_backend(pair):
    d, T = pair
    p = run("register", d / "ref.png", d / "mov.png", "--json", "--backend", "open3d", "--levels", "3")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["backend"] == "open3d"


@pytest.mark.slow
def test_register_records(pair, tmp_path):
    d, T = pair
    rrd = tmp_path / "reg.rrd"
    p = run("register", d / "ref.png", d / "mov.png", "--json", "--record", rrd)
    assert p.returncode == 0, p.stderr
    from pcreg.recording.readback import read_recording, tensor

    logged = tensor(read_recording(rrd).latest("transforms/T_ref_mov", frame=0))
    np.testing.assert_array_equal(logged, np.array(json.loads(p.stdout)["matrix"]))


@pytest.mark.slow
def test_crosscheck_images_json(pair):
    d, _ = pair
    p = run("crosscheck", d / "ref.png", d / "mov.png", "--json")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    assert out["max_corner_disagreement_px"] < 1e-6
    assert out["reference"]["backend"] == "reference" and out["open3d"]["backend"] == "open3d"
    assert out["reference_seconds"] > 0 and out["open3d_seconds"] > 0


def test_crosscheck_of_images_runs_the_stopping_rule_it_is_given(pair, capsys):
    """--relative-fitness and --relative-rmse are the stopping rule of an image cross-check too: they were taken
    and left out, both backends running Open3D's default thresholds (1e-6) under the options the report named."""
    from pcreg.cli import main

    d, _ = pair
    runs = {}
    for given in ((), ("--relative-fitness", "1", "--relative-rmse", "100")):
        assert main(["crosscheck", str(d / "ref.png"), str(d / "mov.png"), "--json", "--levels", "2", *given]) == 0
        runs[given] = json.loads(capsys.readouterr().out)
    default, loose = runs.values()
    assert (loose["config"]["registration"]["icp"]["relative_fitness"],
            loose["config"]["registration"]["icp"]["relative_rmse"]) == (1.0, 100.0)
    for backend in ("reference", "open3d"):  # one step a level: the rule holds after the first
        assert loose[backend]["iterations"] <= 3 < default[backend]["iterations"], (backend, loose[backend])


@pytest.mark.slow
def test_crosscheck_clouds_json(tmp_path):
    rng = np.random.default_rng(0)
    target = rng.uniform(-5, 5, (2000, 3))
    source = tf.apply(np.linalg.inv(np.array([[1, 0, 0, 0.2], [0, 1, 0, -0.1], [0, 0, 1, 0.05], [0, 0, 0, 1.0]])), target)
    np.save(tmp_path / "t.npy", target)
    np.save(tmp_path / "s.npy", source)
    p = run("crosscheck", tmp_path / "t.npy", tmp_path / "s.npy", "--json", "--voxel-size", "0.5", "--max-distance", "1")
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout)
    o3d = out["implementations"]["open3d"]
    assert o3d["rotation_disagreement_deg"] < 1e-6 and o3d["translation_disagreement"] < 1e-6 and o3d["agrees"]


@pytest.mark.parametrize("make_args, message", [
    (lambda d, t: ["register", t / "missing.png", d / "mov.png"], "no such file"),
    (lambda d, t: ["register", t / "text.png", d / "mov.png"], "not an image"),
    (lambda d, t: ["register", t / "empty.png", d / "mov.png"], "empty file"),
    (lambda d, t: ["register", d / "ref.png", t / "flat.png"], "no usable edges"),
    (lambda d, t: ["register", d / "ref.png", t / "tiny.png"], "too small"),
    (lambda d, t: ["register", d / "ref.png", d / "mov.png", "--levels", "0"], "argument --levels: expected an integer in 1..8"),
    (lambda d, t: ["register", d / "ref.png", d / "mov.png", "--model", "warp"], "invalid choice"),
    (lambda d, t: ["register", d / "ref.png", d / "mov.png", "--backend", "open3d", "--model", "affine"],
     "supports the rigid and similarity"),
    (lambda d, t: ["register", d / "ref.png", d / "mov.png", "--out", t / "exists.png"], "exists"),
    (lambda d, t: ["register", d / "ref.png", d / "mov.png", "--record", t / "nodir" / "x" / "r.txt"], ".rrd"),
    (lambda d, t: ["crosscheck", t / "c.npy", d / "mov.png"], "two images or two clouds"),
    (lambda d, t: ["crosscheck", t / "c.npy", t / "nan.npy"], "NaN"),
    (lambda d, t: ["crosscheck", t / "c.npy", t / "c2d.npy"], "c2d.npy: a 2-D cloud, and "),  # named neither file
    (lambda d, t: ["crosscheck", t / "c.npy", t / "c.vtk"], "unknown file type"),
    (lambda d, t: ["crosscheck", t / "c.npy", t / "c.txt"], "c.txt: 4 numbers a line and no first line naming"),
])
def test_bad_input_is_one_line_and_exit_2(pair, tmp_path, make_args, message):
    d, _ = pair
    (tmp_path / "text.png").write_text("hello")
    (tmp_path / "empty.png").write_bytes(b"")
    (tmp_path / "exists.png").write_bytes(b"keep")
    (tmp_path / "c.vtk").write_text("1 2 3")
    (tmp_path / "c.txt").write_text("1 2 3 4")
    cv2.imwrite(str(tmp_path / "flat.png"), np.full((240, 320, 3), 77, np.uint8))
    cv2.imwrite(str(tmp_path / "tiny.png"), np.full((12, 12, 3), 77, np.uint8))
    pts = np.random.default_rng(0).normal(size=(100, 3))
    np.save(tmp_path / "c.npy", pts)
    np.save(tmp_path / "c2d.npy", pts[:, :2])
    bad = pts.copy()
    bad[0, 0] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    p = run(*make_args(d, tmp_path))
    # A flat image is a valid image that cannot be registered: refused (3), not bad input (2).
    assert p.returncode == (3 if message == "no usable edges" else 2), (p.stdout, p.stderr)
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in p.stderr, p.stderr
    assert message in lines[0]
    assert (tmp_path / "exists.png").read_bytes() == b"keep"


# ------------------------------------------------------------------------------------------------
# exit codes: 1 a bug in pcreg, 2 bad input, 3 refused, 130 interrupted
# ------------------------------------------------------------------------------------------------

def _main(argv, capsys):
    from pcreg.cli import main

    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse
        rc = exc.code
    captured = capsys.readouterr()
    return rc, captured.out, captured.err.strip().splitlines()


def _broken_tree(*args, **kwargs):
    raise AttributeError("'NoneType' object has no attribute 'query'")


def test_an_internal_error_is_reported_as_a_bug_with_exit_1(pair, capsys, monkeypatch):
    """An exception pcreg does not raise on purpose, deep inside `pcreg register`, is a bug: exit 1 and one
    line that says so and names it; never a bad-input exit 2 or an InputError."""
    import pcreg.registration.refine as refine

    d, _ = pair
    monkeypatch.delenv("PCREG_TRACEBACK", raising=False)
    monkeypatch.setattr(refine, "build_tree", _broken_tree)
    rc, out, err = _main(["register", d / "ref.png", d / "mov.png", "--json"], capsys)
    assert rc == 1 and out == "", (rc, out, err)
    assert len(err) == 1, err
    assert "a bug in pcreg" in err[0] and "AttributeError: 'NoneType' object has no attribute 'query'" in err[0]
    assert "PCREG_TRACEBACK=1" in err[0]

    monkeypatch.setenv("PCREG_TRACEBACK", "1")
    rc, out, err = _main(["register", d / "ref.png", d / "mov.png"], capsys)
    assert rc == 1 and err[0] == "Traceback (most recent call last):", err
    assert "in _broken_tree" in "\n".join(err) and err[-1] == "AttributeError: 'NoneType' object has no attribute 'query'"


def test_a_bug_in_a_real_process_exits_1_with_one_line(pair):
    """The same through a real interpreter, with a ZeroDivisionError in the ICP step of every level."""
    d, _ = pair
    code = ("import sys, pcreg.registration.steps as steps\n"
            "def broken(*a, **k):\n    return 1 / 0\n"
            "steps.ICP_STEPS = {b: broken for b in steps.ICP_STEPS}\n"
            "from pcreg.cli import main\n"
            f"sys.exit(main(['register', {str(d / 'ref.png')!r}, {str(d / 'mov.png')!r}]))\n")
    env = {k: v for k, v in __import__("os").environ.items() if k != "PCREG_TRACEBACK"}
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 1 and len(lines) == 1, p.stderr
    assert "a bug in pcreg" in lines[0] and "ZeroDivisionError: division by zero" in lines[0]


def test_bad_input_still_exits_2_with_one_line(pair, tmp_path, capsys):
    d, _ = pair
    rc, out, err = _main(["register", tmp_path / "missing.png", d / "mov.png"], capsys)
    assert rc == 2 and len(err) == 1 and err[0] == f"pcreg: error: {tmp_path / 'missing.png'}: no such file", err
    rc, out, err = _main(["register", d / "ref.png", d / "mov.png", "--levels", "0"], capsys)  # argparse
    assert rc == 2 and len(err) == 1 and "--levels" in err[0], err
    rc, out, err = _main(["register", d / "ref.png", d / "mov.png", "--backend", "open3d", "--refine", "point_to_line"],
                         capsys)  # refused by the command (InputError), before the library would
    assert rc == 2 and len(err) == 1 and "reference-backend finish" in err[0], err


def test_an_interrupt_exits_130(pair, capsys, monkeypatch):
    import pcreg.registration.refine as refine

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    d, _ = pair
    monkeypatch.setattr(refine, "build_tree", interrupted)
    rc, out, err = _main(["register", d / "ref.png", d / "mov.png"], capsys)
    assert rc == 130 and len(err) == 1 and "interrupted" in err[0], err


def _not_progress(stderr: str) -> list[str]:
    """The stderr lines that are not a tqdm bar's redraws (``\\r``-separated, ``NN%|``)."""
    parts = [p.strip() for line in stderr.splitlines() for p in line.split("\r")]
    return [p for p in parts if p and "%|" not in p]


@pytest.mark.slow
def test_register_and_crosscheck_say_nothing_on_stderr(pair):
    d, _ = pair
    for args in (("register", d / "ref.png", d / "mov.png", "--json"),
                 ("crosscheck", d / "ref.png", d / "mov.png", "--json"),
                 ("register", d / "ref.png", d / "mov.png", "--backend", "open3d", "--levels", "2")):
        p = run(*args)
        assert p.returncode == 0, p.stderr
        assert _not_progress(p.stderr) == [], (args, p.stderr)


def test_a_png_with_a_damaged_data_chunk_is_one_stderr_line(pair, tmp_path):
    """libpng prints its own complaint on fd 2; it is kept off the terminal (its text goes into
    pcreg's one line)."""
    d, _ = pair
    data = bytearray((d / "ref.png").read_bytes())
    at = data.find(b"IDAT") + 24
    data[at:at + 64] = bytes(b ^ 0x5A for b in data[at:at + 64])
    (tmp_path / "damaged.png").write_bytes(bytes(data))
    for args in (("register", tmp_path / "damaged.png", d / "mov.png"),
                 ("crosscheck", d / "ref.png", tmp_path / "damaged.png")):
        p = run(*args)
        assert p.returncode == 2, p.stderr
        lines = p.stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith("pcreg: error: "), p.stderr
        assert "damaged.png" in lines[0]


def test_python_dash_m_pcreg_is_the_command(tmp_path):
    """``python -m pcreg`` runs the same command line: its help, and a bad input's exit 2 and one line."""
    ok = subprocess.run([sys.executable, "-m", "pcreg", "--help"], capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0 and ok.stdout.startswith("usage: pcreg"), ok.stderr
    version = subprocess.run([sys.executable, "-m", "pcreg", "--version"], capture_output=True, text=True, timeout=120)
    assert version.returncode == 0 and version.stdout == f"pcreg {pcreg.__version__}\n", version.stderr
    bad = subprocess.run([sys.executable, "-m", "pcreg", "register", str(tmp_path / "a.png"), str(tmp_path / "b.png")],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and bad.stderr.strip().splitlines() == [f"pcreg: error: {tmp_path / 'a.png'}: no such file"]


def test_a_commands_description_is_its_first_sentence():
    """"thesis Ch. 4, ..." was cut at "Ch.", and reST's code marks were printed."""
    from pcreg.cli import build_parser

    evaluations = next(a for a in build_parser()._actions if getattr(a, "choices", None) and "evaluate" in a.choices)
    classification = next(a for a in evaluations.choices["evaluate"]._actions
                           if getattr(a, "choices", None) and "classification" in a.choices).choices["classification"]
    assert classification.description == ("pcreg evaluate classification: thesis Ch. 4, naive Bayes alone (cases I-III "
                                          "and the weight search).")
    from pcreg.cli import _first_sentence

    assert _first_sentence("Run it (e.g. here) and see. Next.") == "Run it (e.g. here) and see."


def test_a_frames_bar_past_its_estimated_total_counts_on_without_it(capsys):
    """A video's frame count is an estimate (its duration times its rate): streams joined with ``cat`` or a
    variable rate give more frames than it says. The bar then counts on without a total, never 3/2 or 150%."""
    from pcreg._runner import progress, tick

    with progress(total=2, desc="frames", disable=False) as bar:
        for _ in range(3):
            tick(bar)
            bar.refresh()  # drawn as a person would see it at each frame
        assert (bar.n, bar.total) == (3, None)
    err = capsys.readouterr().err
    assert "2/2" in err and "3/2" not in err and "150%" not in err, err


def test_an_error_longer_than_a_line_is_cut_saying_so(tmp_path, capsys):
    """A message past 500 characters (here one listing a table of 200 classes) ends with ``...``, not in the middle
    of a word."""
    from pcreg.cli import main

    (tmp_path / "labelmap.txt").write_text("".join(f"class{i}:{i},7,7::\n" for i in range(200)))
    (tmp_path / "frames").mkdir()
    for i in range(2):
        cv2.imwrite(str(tmp_path / "frames" / f"f{i}.png"), np.zeros((8, 8, 3), np.uint8))
    cv2.imwrite(str(tmp_path / "key.png"), np.full((8, 8), 250, np.uint8))
    assert main(["run", str(tmp_path / "frames"), "--labels", str(tmp_path / "key.png"), "--classes",
                 str(tmp_path / "labelmap.txt"), "--out", str(tmp_path / "out")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "label value 250 is not a class id" in line
    assert len(line) == len("pcreg: error: ") + 500 and line.endswith("...")


def test_every_option_with_a_default_states_it_in_its_help():
    """What a user reads in --help is what runs: an option whose default is a value (not None or off) says
    "default" in its help, on every command (crosscheck's --iterations 30 and 1e-6 stopping rule were unsaid)."""
    import argparse

    from pcreg.cli import build_parser

    unsaid = []

    def walk(parser, name):
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for sub, sp in a.choices.items():
                    walk(sp, f"{name} {sub}")
            elif (a.option_strings and a.help not in (None, argparse.SUPPRESS)
                  and a.default not in (None, False, argparse.SUPPRESS) and "default" not in a.help):
                unsaid.append(f"{name} {a.option_strings[0]} (default {a.default!r})")

    walk(build_parser(), "pcreg")
    assert not unsaid, unsaid


def test_force_says_what_it_does_on_each_command():
    """``run`` and the evaluations resume an earlier run in --out, and --force starts them over: their help said
    "overwrite existing output files", as it does for commands that write a file or two."""
    from pcreg.cli import build_parser

    def force_help(*path):
        parser = build_parser()
        for name in path:
            parser = next(a for a in parser._actions if hasattr(a, "choices") and isinstance(a.choices, dict)
                          and name in a.choices).choices[name]
        return next(a.help for a in parser._actions if "--force" in a.option_strings)

    for path in (("run",), ("evaluate", "stream"), ("evaluate", "rotation"), ("evaluate", "sequence")):
        assert force_help(*path).startswith("start over: discard what an earlier run in --out finished"), path
    assert force_help("register") == "overwrite existing output files"


def test_importing_pcreg_main_runs_no_command():
    """``import pcreg.__main__`` (a documentation tool or ``pkgutil.walk_packages`` walking the package) ran the command
    line, which ended the importing process with a usage error (``SystemExit(2)``)."""
    run = subprocess.run([sys.executable, "-c", "import pcreg.__main__; print('imported')"], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0 and run.stdout == "imported\n", run.stderr
