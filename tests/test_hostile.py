"""Hostile input, by kind: every case ends in a PcregError (library) or one stderr line and exit 2 (CLI),
in bounded memory. The lock and special-file cases run as real subprocesses (signals: test_interrupts*.py)."""

from __future__ import annotations

import json
import os
import re
import resource
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from pcreg.errors import DatasetError, InputError, PcregError

from _events import HANG

PCREG = [sys.executable, "-m", "pcreg.cli"]
GOOD = np.random.default_rng(0).integers(0, 256, (64, 80, 3), dtype=np.uint8)


# ------------------------------------------------------------------------------------------------
# hostile files
# ------------------------------------------------------------------------------------------------

def _chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))


def png_declaring(w: int, h: int, rows: int = 8) -> bytes:
    """A small PNG whose header declares w x h pixels (a decompression bomb's shape)."""
    row = b"\x00" + b"\x00" * min(w * 3, 1 << 20)
    body = zlib.compress(row * min(rows, h), 9)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + _chunk(b"IDAT", body) + _chunk(b"IEND", b""))


def jpeg_declaring(w: int, h: int) -> bytes:
    sof = struct.pack(">BHHB", 8, h, w, 3) + b"\x01\x11\x00\x02\x11\x00\x03\x11\x00"
    return b"\xff\xd8" + b"\xff\xc0" + struct.pack(">H", len(sof) + 2) + sof + b"\xff\xd9"


def bmp_declaring(w: int, h: int) -> bytes:
    return b"BM" + struct.pack("<IHHI", 54, 0, 0, 54) + struct.pack("<IiiHHIIiiII", 40, w, h, 1, 24, 0, 0, 0, 0, 0, 0)


def tiff_declaring(w: int, h: int) -> bytes:
    entries = [(256, 4, 1, w), (257, 4, 1, h), (258, 3, 1, 8), (259, 3, 1, 1), (262, 3, 1, 1)]
    ifd = struct.pack("<H", len(entries)) + b"".join(struct.pack("<HHII", *e) for e in entries) + b"\0\0\0\0"
    return b"II*\x00" + struct.pack("<I", 8) + ifd


def webp_declaring(w: int, h: int) -> bytes:
    body = b"VP8X" + struct.pack("<I", 10) + b"\0\0\0\0" + (w - 1).to_bytes(3, "little") + (h - 1).to_bytes(3, "little")
    return b"RIFF" + struct.pack("<I", len(body) + 4) + b"WEBP" + body


def ply_binary(n: int) -> bytes:
    pts = np.random.default_rng(1).normal(size=(n, 3)).astype("<f4")
    head = f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    return head.encode() + pts.tobytes()


def ply_ascii(n: int) -> bytes:
    pts = np.random.default_rng(1).normal(size=(n, 3))
    head = f"ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    return (head + "".join(f"{a:.5f} {b:.5f} {c:.5f}\n" for a, b, c in pts)).encode()


def pcd(n: int, kind: str = "binary") -> bytes:
    pts = np.random.default_rng(2).normal(size=(n, 3)).astype("<f4")
    head = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\n"
            f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {kind}\n")
    body = pts.tobytes() if kind == "binary" else "".join(f"{a} {b} {c}\n" for a, b, c in pts).encode()
    return head.encode() + body


def _clouds_whose_lines_or_counts_lie(t):
    """Point clouds whose data does not hold what their headers declare (Open3D reads them wrong, silently)."""
    lines = pcd(200, "ascii").split(b"\n")  # 11 header lines, then the points
    (t / "short_line.pcd").write_bytes(b"\n".join(lines[:60] + [b"1.0 2.0"] + lines[61:]))
    (t / "comma.pcd").write_bytes(b"\n".join(lines[:60] + [b"1,0 2,0 3,0"] + lines[61:]))
    (t / "count_low.pcd").write_bytes(pcd(200, "ascii").replace(b"POINTS 200", b"POINTS 150").replace(b"WIDTH 200", b"WIDTH 150"))
    (t / "count_low_bin.pcd").write_bytes(pcd(200).replace(b"POINTS 200", b"POINTS 150").replace(b"WIDTH 200", b"WIDTH 150"))
    head, body = ply_ascii(50).split(b"end_header\n")
    (t / "four_values.ply").write_bytes(head + b"end_header\n" + body.replace(b"\n", b" 7.0\n"))  # 3 declared
    four = np.random.default_rng(5).normal(size=(50, 4)).astype("<f4")  # 16 bytes a vertex declared as 12
    (t / "four_floats.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 50\nproperty float x\n"
                                        b"property float y\nproperty float z\nelement face 0\n"
                                        b"property list uchar int vertex_indices\nend_header\n" + four.tobytes())


def npy_bytes(arr: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    np.save(buf, arr, allow_pickle=True)
    return buf.getvalue()


def mat_file(path: Path, image, mask=None) -> Path:
    import scipy.io

    d = {"im_rgb": image}
    if mask is not None:
        d["manual_human_labeling_mask"] = mask
    scipy.io.savemat(str(path), d)
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A folder of hostile files by name (shared by the tests of this module; they only add files)."""
    t = tmp_path_factory.mktemp("hostile")
    fifo = t / "fifo.png"
    os.mkfifo(fifo)
    os.mkfifo(t / "fifo.ply")
    os.mkfifo(t / "fifo.npy")
    (t / "folder.png").mkdir()
    (t / "folder.ply").mkdir()
    (t / "empty.png").write_bytes(b"")
    (t / "text.png").write_text("hello, not a png")
    (t / "gif.png").write_bytes(b"GIF89a" + b"\0" * 40)
    (t / "big30k.png").write_bytes(png_declaring(30000, 30000))
    (t / "big100k.png").write_bytes(png_declaring(100000, 100000))
    (t / "zero.png").write_bytes(png_declaring(0, 10))
    (t / "big.jpg").write_bytes(jpeg_declaring(65000, 65000))
    (t / "big.bmp").write_bytes(bmp_declaring(60000, -60000))
    (t / "big.tif").write_bytes(tiff_declaring(70000, 70000))
    (t / "big.webp").write_bytes(webp_declaring(16000, 16000))
    (t / "big.ppm").write_bytes(b"P6\n# comment\n60000 60000\n255\n" + b"\0" * 64)
    ok, enc = cv2.imencode(".png", GOOD)
    (t / "good.png").write_bytes(enc.tobytes())
    (t / "truncated.png").write_bytes(enc.tobytes()[: len(enc) // 2])
    ok, enc = cv2.imencode(".jpg", GOOD)
    (t / "truncated.jpg").write_bytes(enc.tobytes()[:200])
    full = ply_binary(500)
    (t / "trunc_bin.ply").write_bytes(full[: len(full) - 1000])
    full = ply_ascii(300)
    (t / "trunc_ascii.ply").write_bytes(full[: full.index(b"end_header") + 11 + 40 * 100])
    (t / "huge_count.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000000\n"
                                       b"property float x\nproperty float y\nproperty float z\nend_header\n" + b"\0" * 120)
    (t / "no_end.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n")
    (t / "negative.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex -3\nproperty float x\nend_header\n1\n")
    (t / "bad_format.ply").write_bytes(b"ply\nformat weird 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n")
    (t / "ok.ply").write_bytes(ply_binary(400))
    full = pcd(400)
    (t / "trunc_bin.pcd").write_bytes(full[:-800])
    full = pcd(200, "ascii")
    (t / "trunc_ascii.pcd").write_bytes(full[: len(full) // 2])
    (t / "bad_header.pcd").write_bytes(b"VERSION 0.7\nFIELDS x y z\nSIZE four\nPOINTS 10\nDATA binary\n" + b"\0" * 120)
    _clouds_whose_lines_or_counts_lie(t)
    (t / "no_data.pcd").write_bytes(b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\n")
    (t / "double.pcd").write_bytes(pcd(200).replace(b"SIZE 4 4 4", b"SIZE 8 8 8").split(b"DATA binary\n")[0]
                                   + b"DATA binary\n" + np.random.default_rng(2).normal(size=(200, 3)).astype("<f8").tobytes())
    full = npy_bytes(np.random.default_rng(3).normal(size=(300, 3)))
    (t / "trunc.npy").write_bytes(full[:-500])
    (t / "object.npy").write_bytes(npy_bytes(np.array([{"a": 1}, None], dtype=object)))
    (t / "four_cols.npy").write_bytes(npy_bytes(np.zeros((50, 4))))
    (t / "strings.npy").write_bytes(npy_bytes(np.array(["a", "b"])))
    (t / "mask.npy").write_bytes(npy_bytes(np.random.default_rng(4).random((300, 3)) > 0.5))
    (t / "huge_shape.npy").write_bytes(npy_bytes(np.zeros((2, 3)))
                                       .replace(b"(2, 3)", b"(10**12, 3)".replace(b"10**12", b"999999999999")))
    (t / "random.npy").write_bytes(os.urandom(300))
    # a header numpy can parse neither as a literal nor, tokenized again, as Python 2's
    (t / "bad_header.npy").write_bytes(full.replace(b"(300, 3), }", b"(300, 3\x00 }", 1))
    (t / "garbage.xyz").write_text("1 2 3\nfoo bar\n4 5 6\n7 8\n" + "".join(f"{i} 1 2\n" for i in range(30)))
    (t / "short.pts").write_text("4\n1 2 3\n4 5 6\n")
    (t / "far.xyz").write_text("\n".join("1e300 0 0" if i == 0 else f"{i} {i % 7} {i % 3}" for i in range(50)))
    (t / "xy.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 300\nproperty float x\n"
                               b"property float y\nend_header\n" + np.arange(600, dtype="<f4").tobytes())
    (t / "empty_init.txt").write_text("")
    (t / "zero_init.txt").write_text("0 0 0 0\n0 0 0 0\n0 0 0 0\n0 0 0 0\n")
    twice = t / "twice"
    (twice / "images").mkdir(parents=True)
    (twice / "labels").mkdir()
    cv2.imwrite(str(twice / "images" / "a.png"), GOOD)
    cv2.imwrite(str(twice / "images" / "a.jpg"), GOOD)
    cv2.imwrite(str(twice / "labels" / "a.png"), np.zeros(GOOD.shape[:2], np.uint8))
    lagr = t / "lagr"
    lagr.mkdir()
    return t


def _lagr(tmp_path: Path, image, mask=None) -> Path:
    d = tmp_path / "lagr_set"
    d.mkdir(exist_ok=True)
    mat_file(d / "frame001.mat", image, mask)
    return d


# ------------------------------------------------------------------------------------------------
# library: every kind raises a PcregError subclass, nothing else
# ------------------------------------------------------------------------------------------------

def _load_image(name, **kw):
    def f(t):
        from pcreg.registration.clouds import load_image

        return load_image(t / name, **kw)
    return f


def _load_cloud(name):
    def f(t):
        from pcreg.implementations.crosscheck import load_cloud

        return load_cloud(t / name)
    return f


def _register(ref=GOOD, mov=GOOD, init=None, **options):
    def f(t):
        from pcreg.registration.api import register
        from pcreg.registration.config import RegisterConfig

        return register(ref, mov, config=RegisterConfig.of(**options), init=init)
    return f


def _warp(img, T=np.eye(3), **kw):
    def f(t):
        from pcreg.registration.warp import warp

        return warp(img, T, **kw)
    return f


CLOUD = np.random.default_rng(4).normal(size=(60, 3))


def _icp_call(src, tgt, *, init=None, **kw):
    """``pcreg.icp`` with ``kw`` as its options: an ICPOptions, the voxel schedule's keywords as its
    VoxelSchedule (no schedule without voxel sizes; empty sequences as None)."""
    import pcreg

    keys = ("voxel_sizes", "max_correspondence_distances", "max_iterations")
    if any(k in kw for k in keys):
        sched = {k: kw.pop(k) for k in keys if k in kw}
        sched = {k: None if isinstance(v, list) and not v else v for k, v in sched.items()}
        sizes = sched.pop("voxel_sizes", (1.0,))
        if sizes is not None:
            kw["schedule"] = pcreg.VoxelSchedule(sizes, **sched)
    return pcreg.icp(src, tgt, pcreg.ICPOptions(**kw), init=init)


def _icp(src=CLOUD, tgt=CLOUD, **kw):
    def f(t):
        return _icp_call(src, tgt, **kw)
    return f


def _propagator(**kw):
    def f(t):
        from pcreg import Propagator

        labels = np.zeros(GOOD.shape[:2], np.uint8)
        labels[32:] = 1
        return Propagator.from_key_frame(GOOD, labels, **kw)
    return f


def _error_rate(predicted, truth):
    def f(t):
        from pcreg import error_rate

        return error_rate(predicted, truth)
    return f


def _call(path: str, *args, **kw):
    """``pcreg.<path>(*args, **kw)``, imported when called."""
    def f(t):
        import importlib

        module, _, name = path.rpartition(".")
        return getattr(importlib.import_module(module), name)(*args, **kw)
    return f


def _nb(**kw):
    def f(t):
        from pcreg.classification.bayes import NaiveBayesPixelClassifier

        return NaiveBayesPixelClassifier(("rgb",), **kw)
    return f


def _weight_search(**kw):
    def f(t):
        from pcreg.classification.weight_search import thesis_weight_search

        return thesis_weight_search(GOOD, np.zeros(GOOD.shape[:2], np.uint8), **kw)
    return f


def _lagr_load(image, mask=None):
    def f(t):
        from pcreg.datasets import load_lagr

        return load_lagr(_lagr(t, image, mask))
    return f


def _lagr_bytes(data: bytes):
    def f(t):
        from pcreg.datasets import load_lagr

        d = t / "lagr_bytes"
        d.mkdir()
        (d / "frame001.mat").write_bytes(data)
        return load_lagr(d)
    return f


LIBRARY = {
    # image files
    "image_missing": (_load_image("missing.png"), "no such file"),
    "image_is_folder": (_load_image("folder.png"), "folder"),
    "image_is_fifo": (_load_image("fifo.png"), "not a regular file"),
    "image_is_char_device": (lambda t: __import__("pcreg.registration.clouds", fromlist=["x"]).load_image("/dev/zero"),
                             "not a regular file"),
    "image_empty": (_load_image("empty.png"), "empty"),
    "image_text": (_load_image("text.png"), "not an image"),
    "image_gif": (_load_image("gif.png"), "not an image"),
    "png_30000x30000": (_load_image("big30k.png"), "exceeds the limit"),
    "png_100000x100000": (_load_image("big100k.png"), "exceeds the limit"),
    "png_zero_width": (_load_image("zero.png"), "damaged PNG header"),
    "jpeg_65000x65000": (_load_image("big.jpg"), "exceeds the limit"),
    "bmp_60000x60000": (_load_image("big.bmp"), "exceeds the limit"),
    "tiff_70000x70000": (_load_image("big.tif"), "exceeds the limit"),
    "webp_16000x16000": (_load_image("big.webp"), "exceeds the limit"),
    "ppm_60000x60000": (_load_image("big.ppm"), "exceeds the limit"),
    "png_truncated": (_load_image("truncated.png"), "cannot decode"),
    "jpeg_truncated": (_load_image("truncated.jpg"), "decode"),
    "max_pixels_below_image": (_load_image("good.png", max_pixels=100), "exceeds the limit of 100"),
    "max_pixels_zero": (_load_image("good.png", max_pixels=0), "max_pixels"),
    # image arrays
    "float_image_above_1": (_register(ref=GOOD.astype(np.float32)), "[0, 1]"),
    "float_image_negative": (_register(mov=-GOOD.astype(np.float64) / 255), "[0, 1]"),
    "image_nan": (_register(ref=np.full((64, 80, 3), np.nan)), "NaN"),
    "image_int64": (_register(ref=GOOD.astype(np.int64)), "dtype"),
    "image_complex": (_register(ref=GOOD.astype(np.complex64)), "dtype"),
    "image_object": (_register(ref=np.empty((64, 80, 3), dtype=object)), "dtype"),
    "image_1d": (_register(ref=np.zeros(100, np.uint8)), "shape"),
    "image_4d": (_register(ref=np.zeros((2, 64, 80, 3), np.uint8)), "shape"),
    "image_zero_size": (_register(ref=np.zeros((0, 80, 3), np.uint8)), "empty"),
    "image_list": (_register(ref=[[1, 2], [3, 4]]), "numpy array"),
    # register keywords
    "levels_2_5": (_register(levels=2.5), "levels must be an integer"),
    "levels_0": (_register(levels=0), "levels"),
    "levels_9": (_register(levels=9), "levels"),
    "levels_true": (_register(levels=True), "levels"),
    "angle_step_0": (_register(angle_step=0), "angle_step"),
    "angle_step_nan": (_register(angle_step=float("nan")), "angle_step"),
    "n_candidates_0": (_register(n_candidates=0), "n_candidates"),
    "iterations_negative": (_register(iterations=-1), "iterations"),
    "max_distance_inf": (_register(max_correspondence_distance=float("inf")), "finite"),
    "init_singular": (_register(init=np.zeros((3, 3))), "singular"),
    "init_nan": (_register(init=np.full((3, 3), np.nan)), "finite"),
    "init_wrong_shape": (_register(init=np.eye(4)), "3x3"),
    "init_text": (_register(init="sideways"), "init"),
    "backend_unknown": (_register(backend="magic"), "backend"),
    "model_unknown": (_register(model="warp"), "model"),
    "seed_negative": (_register(seed=-1), "seed"),
    # warp
    "warp_int64": (_warp(np.zeros((10, 10), np.int64)), "dtype"),
    "warp_shape_0x0": (_warp(GOOD, shape=(0, 0)), "shape"),
    "warp_shape_float": (_warp(GOOD, shape=(2.5, 3)), "shape"),
    "warp_shape_huge": (_warp(GOOD, shape=(30000, 30000)), "limit"),
    "warp_singular": (_warp(GOOD, T=np.zeros((3, 3))), "singular"),
    "warp_nan_matrix": (_warp(GOOD, T=np.full((3, 3), np.nan)), "finite"),
    "warp_fill_nan": (_warp(GOOD, fill=float("nan")), "fill"),
    "warp_matrix_1e300": (_warp(GOOD, T=np.diag([1e300, 1e300, 1.0])), "|m| <= 1e12"),
    "cloud_complex": (_icp(src=CLOUD.astype(complex)), "numeric"),
    "ply_without_z": (_load_cloud("xy.ply"), "without the z property"),
    "propagator_affine_on_open3d": (_propagator(model="affine", backend="open3d"), "open3d backend"),
    "propagator_weight_1e39": (_propagator(weight=1e39), "weight"),
    "error_rate_of_fractions": (_error_rate(np.full((4, 4), 0.5), np.zeros((4, 4), int)), "integer"),
    "error_rate_of_none": (_error_rate(None, None), "integer"),
    "synthetic_over_the_pixel_limit": (_call("pcreg.synthetic", "syn1a", 1, width=32767, height=32767),
                                       "pixel limit"),
    "synthetic_a_billion_frames": (_call("pcreg.synthetic", "syn1a", 10**9), "pixel limit"),
    "fuse_weight_nan": (_call("pcreg.classification.fusion.fuse", np.zeros((2, 2)), np.zeros((2, 2)),
                              weight=float("nan")), "weight"),
    "fuse_weight_none": (_call("pcreg.classification.fusion.fuse", np.zeros((2, 2)), np.zeros((2, 2)), weight=None),
                         "weight"),
    "labels_from_nan_log_odds": (_call("pcreg.classification.fusion.labels_from_log_odds", np.full((2, 2), np.nan)),
                                 "NaN"),
    "fusion_sigma_inf": (_call("pcreg.classification.fusion.FusionConfig", sigma=float("inf")), "sigma"),
    "choose_weight_empty_grid": (_call("pcreg.classification.fusion.choose_weight", [], grid=[]), "grid"),
    "propagator_weight_none": (_propagator(weight=None), "weight"),
    "propagator_fusion_none": (_propagator(fusion=None), "fusion"),
    "check_pi_none": (_call("pcreg.classification.fusion.check_pi", None), "must be a number"),
    "class_prior_of_none": (_call("pcreg.pipeline.prior.class_prior", None), "fitted two-class"),
    "error_rate_truth_negative": (_error_rate(np.zeros((4, 4), int), np.full((4, 4), -1)), "truth labels"),
    # point clouds (arrays)
    "cloud_coordinates_1e300": (_icp(src=CLOUD * 1e300), "out of range"),
    "cloud_nan": (_icp(src=np.vstack([CLOUD, [[np.nan, 0, 0]]])), "NaN"),
    "cloud_empty": (_icp(src=np.zeros((0, 3))), "empty"),
    "cloud_strings": (_icp(src=np.array([["a", "b", "c"]])), "numeric"),
    "icp_max_iteration_2_5": (_icp(max_iteration=2.5), "max_iteration"),
    "icp_voxel_size_zero": (_icp(voxel_sizes=(1.0, 0.0)), "voxel_sizes"),
    "icp_init_singular": (_icp(init=np.zeros((4, 4))), "singular"),
    "icp_trim_fraction_2": (_icp(trim_fraction=2.0), "trim_fraction"),
    # naive Bayes
    "var_smoothing_negative": (_nb(var_smoothing=-1), "var_smoothing"),
    "var_smoothing_nan": (_nb(var_smoothing=float("nan")), "var_smoothing"),
    "priors_bad_sum": (_nb(priors=(0.9, 0.9)), "priors"),
    "n_trials_0": (_weight_search(n_trials=0), "n_trials"),
    # point-cloud files
    "ply_truncated_binary": (_load_cloud("trunc_bin.ply"), "truncated PLY"),
    "ply_truncated_ascii": (_load_cloud("trunc_ascii.ply"), "truncated PLY"),
    "ply_huge_vertex_count": (_load_cloud("huge_count.ply"), "exceed the limit"),
    "ply_no_end_header": (_load_cloud("no_end.ply"), "end_header"),
    "ply_negative_count": (_load_cloud("negative.ply"), "negative"),
    "ply_unknown_format": (_load_cloud("bad_format.ply"), "format"),
    "ply_is_fifo": (_load_cloud("fifo.ply"), "not a regular file"),
    "ply_is_folder": (_load_cloud("folder.ply"), "folder"),
    "pcd_truncated_binary": (_load_cloud("trunc_bin.pcd"), "truncated PCD"),
    "pcd_truncated_ascii": (_load_cloud("trunc_ascii.pcd"), "truncated"),
    "pcd_damaged_header": (_load_cloud("bad_header.pcd"), "damaged PCD header"),
    "pcd_a_line_of_two_numbers": (_load_cloud("short_line.pcd"), "data line 50 ('1.0 2.0') is not 3 numbers"),
    "pcd_decimal_commas": (_load_cloud("comma.pcd"), "('1,0 2,0 3,0') is not 3 numbers"),
    "pcd_count_lies_low_ascii": (_load_cloud("count_low.pcd"), "declares 150 points, the file holds more"),
    "pcd_count_lies_low_binary": (_load_cloud("count_low_bin.pcd"), "more points than declared"),
    "ply_four_values_a_vertex_of_three": (_load_cloud("four_values.ply"), "vertex line 1"),
    "ply_four_floats_a_vertex_of_three_then_no_face": (_load_cloud("four_floats.ply"), "more vertices than declared"),
    "pcd_no_data_line": (_load_cloud("no_data.pcd"), "DATA"),
    "pcd_binary_doubles": (_load_cloud("double.pcd"), "8-byte numbers is not read correctly"),  # Open3D: zeros
    "npy_truncated": (_load_cloud("trunc.npy"), "truncated .npy"),
    "npy_pickled_objects": (_load_cloud("object.npy"), "numeric"),
    "npy_four_columns": (_load_cloud("four_cols.npy"), "(N, 2) or (N, 3)"),
    "npy_strings": (_load_cloud("strings.npy"), "numeric"),
    "npy_true_false_values": (_load_cloud("mask.npy"), "a mask, not coordinates"),
    "npy_huge_shape": (_load_cloud("huge_shape.npy"), "limit"),
    "npy_random_bytes": (_load_cloud("random.npy"), "not a numpy array"),
    "npy_unparsable_header": (_load_cloud("bad_header.npy"), "not a numpy array"),
    "npy_is_fifo": (_load_cloud("fifo.npy"), "not a regular file"),
    "xyz_coordinates_1e300": (_load_cloud("far.xyz"), "out of range"),
    "xyz_lines_that_are_not_points": (_load_cloud("garbage.xyz"), "point line 2 ('foo bar') is not 3 numbers"),
    "pts_count_mismatch": (_load_cloud("short.pts"), "declares 4 points"),
    "folder_two_images_one_frame": (lambda t: __import__("pcreg.datasets", fromlist=["x"]).load_folder(t / "twice"),
                                    "share a frame name"),
    # LAGR .mat
    "mat_full_of_nan": (_lagr_load(np.full((20, 16, 3), np.nan)), "NaN"),
    "mat_values_above_255": (_lagr_load(np.full((20, 16, 3), 1e6)), "outside 0..255"),
    "mat_text_image": (_lagr_load(np.array(["abc", "def"])), "im_rgb"),
    "mat_random_bytes": (_lagr_bytes(os.urandom(2000)), "cannot read .mat"),
    "mat_mask_out_of_range": (_lagr_load(np.zeros((20, 16, 3), np.uint8), np.full((20, 16), 7.0)), "outside"),
}


@pytest.mark.parametrize("kind", sorted(LIBRARY))
def test_library_raises_pcreg_errors_only(files, kind):
    call, message = LIBRARY[kind]
    expected = DatasetError if kind.startswith(("mat_", "folder_")) else InputError  # a dataset's files
    with pytest.raises(PcregError) as err:
        call(files)
    assert type(err.value) is expected, repr(err.value)
    assert message in str(err.value), str(err.value)
    assert "\n" not in str(err.value)


def test_a_damaged_image_is_named_in_pcregs_words_not_opencvs_log(files):
    """The codec's own reason is kept, without the prefix OpenCV logs it with (level, time, source line)."""
    with pytest.raises(InputError) as err:
        LIBRARY["png_truncated"][0](files)
    text = str(err.value)
    assert "cannot decode image (" in text and "[ WARN" not in text and ".cpp:" not in text, text


BAD_VALUES = [None, "x", -1, 2.5, float("nan"), float("inf"), 1e300, [], {}, np.zeros((3, 3)), True, object()]
PUBLIC_CALLS = {
    "register": (lambda **kw: __import__("pcreg").register(GOOD, GOOD, **kw),
                 ["config", "backend", "model", "init", "reference_mask", "moving_mask", "callback"]),
    "RegisterConfig": (lambda **kw: __import__("pcreg").RegisterConfig.of(**kw),
                       ["backend", "model", "levels", "iterations", "init", "sampler", "max_points", "refine",
                        "weights", "angle_step", "n_candidates", "canny_percentile", "seed", "generators",
                        "max_correspondence_distance", "relative_fitness", "relative_rmse", "reference_max_points",
                        "min_inlier_ratio", "inlier_tolerance"]),
    "icp": (lambda **kw: _icp_call(CLOUD, CLOUD, **kw),
            ["backend", "model", "max_correspondence_distance", "init", "max_iteration", "voxel_sizes",
             "max_iterations", "weights", "trim_fraction", "metric", "rotation"]),
    "image_cloud": (lambda **kw: __import__("pcreg").image_cloud(GOOD, **kw),
                    ["sampler", "max_points", "level", "canny_percentile"]),
    "cloud_pyramid": (lambda **kw: __import__("pcreg.registration.clouds", fromlist=["x"]).cloud_pyramid(GOOD, **kw), ["levels", "max_points"]),
    "warp": (lambda **kw: __import__("pcreg").warp(GOOD, np.eye(3), **kw), ["shape", "interpolation", "fill"]),
    "synthetic": (lambda **kw: __import__("pcreg").synthetic("syn1a", **{"n_frames": 2, "width": 32, "height": 24, **kw}), ["n_frames", "seed", "width", "height"]),
    "load_dataset": (lambda **kw: __import__("pcreg").load_dataset("synthetic:syn1a", **{"n_frames": 2, "size": (32, 24), **kw}),
                     ["n_frames", "size", "seed"]),
    "NaiveBayesPixelClassifier": (lambda **kw: __import__("pcreg.classification.bayes", fromlist=["x"]).NaiveBayesPixelClassifier(**kw),
                                  ["features", "weights", "var_smoothing", "priors"]),
}


# Values among BAD_VALUES that a keyword accepts, and the type of the result; every other value is refused
# with an InputError whose message names the keyword (its "name" here when the message says it otherwise).
ACCEPTED = {
    ("register", "backend"): {None}, ("register", "model"): {None}, ("register", "init"): {None},
    ("register", "reference_mask"): {None}, ("register", "moving_mask"): {None}, ("register", "callback"): {None},
    ("RegisterConfig", "max_points"): {None}, ("RegisterConfig", "refine"): {None},
    ("RegisterConfig", "angle_step"): {2.5}, ("RegisterConfig", "canny_percentile"): {2.5},
    ("RegisterConfig", "reference_max_points"): {None}, ("RegisterConfig", "max_correspondence_distance"): {2.5},
    ("RegisterConfig", "relative_fitness"): {2.5, 1e300}, ("RegisterConfig", "relative_rmse"): {2.5, 1e300},
    ("RegisterConfig", "min_inlier_ratio"): {None}, ("RegisterConfig", "inlier_tolerance"): {2.5, 1e300},
    ("icp", "max_correspondence_distance"): {None, 2.5, 1e300}, ("icp", "init"): {None},
    ("icp", "voxel_sizes"): {None, "[]"}, ("icp", "max_iterations"): {None, "[]"},
    ("image_cloud", "max_points"): {None}, ("image_cloud", "canny_percentile"): {2.5},
    ("cloud_pyramid", "max_points"): {None},
    ("warp", "shape"): {None}, ("warp", "fill"): {-1, 2.5, 1e300},
    ("load_dataset", "n_frames"): {None}, ("load_dataset", "size"): {None},
    ("NaiveBayesPixelClassifier", "weights"): {None}, ("NaiveBayesPixelClassifier", "priors"): {None},
    ("NaiveBayesPixelClassifier", "var_smoothing"): {2.5, 1e300},
}
RESULT = {"register": "RegistrationResult", "RegisterConfig": "RegisterConfig", "icp": "RegistrationResult", "image_cloud": "ImageCloud",
          "cloud_pyramid": "list", "warp": "tuple", "synthetic": "list", "load_dataset": "dict",
          "NaiveBayesPixelClassifier": "NaiveBayesPixelClassifier"}
NAMED = {("register", "reference_mask"): "reference_mask", ("register", "model"): "model",
         ("RegisterConfig", "model"): "model", ("RegisterConfig", "weights"): "weights",
         ("icp", "model"): "model", ("icp", "weights"): "weights", ("warp", "interpolation"): "interpolation",
         ("NaiveBayesPixelClassifier", "features"): "feature", ("NaiveBayesPixelClassifier", "weights"): "weights",
         ("synthetic", "seed"): "seed"}


def _accepted(function: str, kw: str, value) -> bool:
    allowed = ACCEPTED.get((function, kw), set())
    if isinstance(value, list) and not value:
        return "[]" in allowed
    if value is None or (isinstance(value, (int, float)) and not isinstance(value, bool)):
        return value in allowed  # NaN equals nothing
    return False


@pytest.mark.parametrize("function", sorted(PUBLIC_CALLS))
def test_public_api_wrong_types_raise_input_errors_naming_the_parameter(function):
    """Every keyword of the public functions, given values of the wrong type or range: an InputError whose
    one-line message names the keyword, or, for the values listed in ACCEPTED, a result of the expected type."""
    call, keywords = PUBLIC_CALLS[function]
    for kw in keywords:
        name = NAMED.get((function, kw), kw)
        for value in BAD_VALUES:
            label = f"{function}({kw}={value!r:.40})"
            if _accepted(function, kw, value):
                assert type(call(**{kw: value})).__name__ == RESULT[function], label
                continue
            with pytest.raises(InputError) as err:
                call(**{kw: value})
            message = str(err.value)
            assert name in message and "\n" not in message, f"{label}: {message}"


def test_png_bomb_is_refused_before_decoding(files, monkeypatch):
    from pcreg.registration.clouds import load_image

    def decoded(*args, **kwargs):
        raise AssertionError("the bomb reached the decoder")

    monkeypatch.setattr(cv2, "imdecode", decoded)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(InputError, match="exceeds the limit"):
        load_image(files / "big30k.png")
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 50_000  # KiB


def test_pixel_limit_can_be_raised(files, monkeypatch):
    from pcreg.registration.clouds import load_image

    with pytest.raises(InputError, match=f"exceeds the limit of {64 * 80 - 1}"):
        load_image(files / "good.png", max_pixels=64 * 80 - 1)
    assert load_image(files / "good.png", max_pixels=64 * 80).shape == (64, 80, 3)
    monkeypatch.setenv("PCREG_MAX_PIXELS", "100")
    with pytest.raises(InputError, match="limit of 100"):
        load_image(files / "good.png")


def test_arrays_are_held_to_the_pixel_limit_as_files_are(files, monkeypatch):
    """Images and clouds given as arrays to register, register_dense, image_cloud and icp are refused past the
    pixel (point) limit in the words of a file's refusal (they were taken whatever their size); a file read
    with its own higher limit is converted under that limit."""
    import pcreg
    from pcreg.cloud_reader import load_cloud
    from pcreg.registration.clouds import load_image

    image, points = np.zeros((64, 80, 3), np.uint8), np.random.default_rng(0).normal(size=(400, 2))
    monkeypatch.setenv("PCREG_MAX_PIXELS", "100")
    said = "exceeds the limit of 100 pixels (raise it with PCREG_MAX_PIXELS or --max-pixels)"
    for call in (lambda: pcreg.register(image, image), lambda: pcreg.register_dense(image, image),
                 lambda: pcreg.image_cloud(image)):
        with pytest.raises(InputError, match=re.escape(f"image: 80x64 px {said}")):
            call()
    with pytest.raises(InputError, match=re.escape("source: 400 points exceed the limit of 100 points (raise it with "
                                                   "PCREG_MAX_PIXELS or --max-pixels)")):
        pcreg.icp(points, points)
    assert load_image(files / "good.png", max_pixels=64 * 80).shape == (64, 80, 3)
    assert load_cloud(files / "ok.ply", max_points=400).shape == (400, 3)
    monkeypatch.setenv("PCREG_MAX_PIXELS", str(64 * 80))
    assert pcreg.image_cloud(image).shape[:2] == (64, 80) and pcreg.icp(points, points).fitness == 1.0


def test_a_complete_ply_still_loads(files):
    from pcreg.implementations.crosscheck import load_cloud

    assert load_cloud(files / "ok.ply").shape == (400, 3)


def test_warp_keeps_float16(files):
    from pcreg.registration.warp import warp

    out, valid = warp(np.ones((10, 12), np.float16), np.eye(3))
    assert out.dtype == np.float16 and valid.all()


# ------------------------------------------------------------------------------------------------
# command line: one stderr line, exit 2, no traceback
# ------------------------------------------------------------------------------------------------

def cli(argv: list[str], capsys) -> tuple[int, list[str]]:
    from pcreg.cli import main

    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse
        rc = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    return rc, err


CLI = {
    "view_size_negative": (["view", "{t}/x.rrd", "--size", "0x-5"], "--size"),
    "view_timeout_nan": (["view", "{t}/x.rrd", "--timeout", "nan"], "--timeout"),
    "angles_nan": (["evaluate", "rotation", "--angles", "nan"], "--angles"),
    # the refusal said "choose a larger scale", which evaluate stream has no option for
    "stream_method_frames_too_small": (["evaluate", "stream", "--data", "synthetic:syn1a", "--size", "64x48", "--frames",
                                        "3", "--methods", "plain,pcreg_flow", "--out", "{t}/o"],
                                       "--methods pcreg_flow: scale 0.5 works at 32x24"),
    "angles_inf": (["evaluate", "rotation", "--angles", "0,inf"], "--angles"),
    "angles_step_tiny": (["evaluate", "rotation", "--angles", "0:360:1e-9"], "limit"),
    "angles_range_nan": (["evaluate", "rotation", "--angles", "0:nan:1"], "--angles"),
    "fusion_weight_inf": (["evaluate", "sequence", "--fusion-weight", "inf"], "--fusion-weight"),
    "fusion_weight_nan": (["evaluate", "sequence", "--fusion-weight", "nan"], "--fusion-weight"),
    "register_max_distance_inf": (["register", "{t}/good.png", "{t}/good.png", "--max-distance", "inf"], "--max-distance"),
    "crosscheck_max_distance_nan": (["crosscheck", "{t}/good.png", "{t}/good.png", "--max-distance", "nan"], "--max-distance"),
    "crosscheck_voxel_inf": (["crosscheck", "{t}/ok.ply", "{t}/ok.ply", "--voxel-sizes", "1,inf"], "--voxel-sizes"),
    "max_pixels_zero": (["register", "{t}/good.png", "{t}/good.png", "--max-pixels", "0"], "--max-pixels"),
    "max_pixels_text": (["register", "{t}/good.png", "{t}/good.png", "--max-pixels", "lots"], "--max-pixels"),
    "classification_size_negative": (["evaluate", "classification", "--size", "0x-5"], "--size"),
    "sequence_size_huge": (["evaluate", "sequence", "--size", "100000x100000"], "--size"),
    "sequence_frames_huge": (["evaluate", "sequence", "--frames", "10000000000"], "--frames"),
    "sequence_increment_huge": (["evaluate", "sequence", "--increments", "1,99999999999"], "--increments"),
    "workers_zero": (["evaluate", "rotation", "--workers", "0"], "--workers"),
    "workers_huge": (["evaluate", "classification", "--workers", "100000"], "--workers"),
    "seed_negative": (["evaluate", "classification", "--seed", "-4"], "--seed"),
    "levels_nine": (["evaluate", "rotation", "--levels", "9"], "--levels"),
    "trials_zero": (["evaluate", "classification", "--trials", "0"], "--trials"),
    "register_out_is_folder_with_force": (["register", "{t}/good.png", "{t}/good.png", "--out", "{t}/folder.png",
                                           "--force"], "folder"),
    "register_png_30000x30000": (["register", "{t}/big30k.png", "{t}/good.png"], "exceeds the limit"),
    "register_fifo": (["register", "{t}/fifo.png", "{t}/good.png"], "not a regular file"),
    "register_dev_zero": (["register", "/dev/zero", "{t}/good.png"], "not a regular file"),
    "register_float_tiff_text": (["register", "{t}/text.png", "{t}/good.png"], "not an image"),
    "crosscheck_truncated_ply": (["crosscheck", "{t}/ok.ply", "{t}/trunc_bin.ply", "--json"], "truncated PLY"),
    "crosscheck_coordinates_1e300": (["crosscheck", "{t}/ok.ply", "{t}/far.xyz"], "out of range"),
    "classification_data_missing": (["evaluate", "classification", "--data", "camvid:{t}/nothing", "--out", "{t}/o"],
                                    "no such folder"),
    "crosscheck_voxel_1e-300": (["crosscheck", "{t}/ok.ply", "{t}/ok.ply", "--voxel-sizes", "1e-300"], "too small"),
    "synthetic_frames_over_the_pixel_limit": (["evaluate", "sequence", "--size", "8192x8192", "--out", "{t}/o"],
                                              "pixel limit"),
    "synthetic_data_too_big_for_memory": (["evaluate", "rotation", "--frames", "100000", "--out", "{t}/o"],
                                          "G pixels"),
    "workers_over_4x_cpus": (["evaluate", "rotation", "--data", "synthetic:syn1a", "--frames", "2", "--size",
                              "48x36", "--workers", "1000", "--out", "{t}/o"], "CPUs"),
    "crosscheck_init_fifo": (["crosscheck", "{t}/ok.ply", "{t}/ok.ply", "--init", "{t}/fifo.npy"], "not a regular file"),
    "crosscheck_init_nan": (["crosscheck", "{t}/ok.ply", "{t}/ok.ply", "--init", "{t}/nan.txt"], "finite"),
    "crosscheck_relative_fitness_nan": (["crosscheck", "{t}/ok.ply", "{t}/ok.ply", "--relative-fitness", "nan"],
                                        "--relative-fitness"),
    "crosscheck_suite_bad_params": (["crosscheck", "--suite", "{t}/suite"], "params.json: max_correspondence_distance must be a number, got 'far'"),
    "sequence_lagr_nan": (["evaluate", "sequence", "--data", "lagr:{t}/lagr_nan", "--out", "{t}/o"], "NaN"),
    "register_out_not_png_or_jpeg": (["register", "{t}/good.png", "{t}/good.png", "--out", "{t}/w.webp"],
                                     "name it .png"),
    "register_out_a_folder_name": (["register", "{t}/good.png", "{t}/good.png", "--out", "{t}/w/"], "name it .png"),
    "crosscheck_with_py_without_a_function": (["crosscheck", "{t}/ok.ply", "{t}/ok.ply", "--with", "py:"],
                                              "py:MODULE:FUNCTION"),
    "crosscheck_with_an_unclosed_quote": (["crosscheck", "{t}/ok.ply", "{t}/ok.ply", "--with", 'cmd:"x {out}'],
                                          "cannot parse"),
    "crosscheck_with_nothing": (["crosscheck", "{t}/ok.ply", "{t}/ok.ply", "--with", ""], "argument --with: expected a value"),
    "stream_names_no_dataset": (["evaluate", "stream", "--data", "synthetic:,", "--out", "{t}/o"],
                                "names no synthetic preset"),
    "stream_classes_of_another_two_class_table": (["evaluate", "stream", "--classes", "davis", "--out", "{t}/o"],
                                                  "the two-class evaluation scores ground and obstacle"),
    "stream_names_no_dataset_after_the_colon": (["evaluate", "stream", "--data", "synthetic:", "--out", "{t}/o"],
                                                "names no synthetic preset"),
    "sequence_scores_no_pair": (["evaluate", "sequence", "--data", "synthetic:syn1a", "--frames", "6", "--size",
                                 "64x48", "--increments", "1", "--levels", "8", "--out", "{t}/o8"],
                                "no pair was scored"),
    "crosscheck_init_empty": (["crosscheck", "{t}/ok.ply", "{t}/ok.ply", "--init", "{t}/empty_init.txt"], "empty"),
    "crosscheck_init_singular": (["crosscheck", "{t}/ok.ply", "{t}/ok.ply", "--init", "{t}/zero_init.txt"],
                                 "singular"),
    "crosscheck_iterations_over_the_limit": (["crosscheck", "{t}/ok.ply", "{t}/ok.ply", "--iterations", "1000000"],
                                             "--iterations"),
    "crosscheck_voxel_size_on_images": (["crosscheck", "{t}/good.png", "{t}/good.png", "--voxel-size", "3"],
                                        "point clouds"),
    "sequence_fusion_frames_over_frames": (["evaluate", "sequence", "--frames", "12", "--fusion-frames", "13",
                                            "--out", "{t}/o"], "--fusion-frames"),
    "sequence_model_open3d_cannot_fit": (["evaluate", "sequence", "--model", "projective", "--backend", "open3d",
                                          "--out", "{t}/o"], "open3d backend"),
}


@pytest.mark.parametrize("kind", sorted(CLI))
def test_cli_one_line_exit_2(files, capsys, kind):
    argv, message = CLI[kind]
    if kind == "sequence_lagr_nan":
        mat_file((files / "lagr_nan").mkdir() or files / "lagr_nan" / "frame001.mat", np.full((20, 16, 3), np.nan),
                 np.zeros((20, 16)))
    (files / "nan.txt").write_text("1 0 0 0\n0 nan 0 0\n0 0 1 0\n0 0 0 1\n")
    if kind == "crosscheck_suite_bad_params":
        (files / "suite" / "c1").mkdir(parents=True)
        (files / "suite" / "index.json").write_text(json.dumps({"format": 1, "cases": ["c1"]}))
        (files / "suite" / "c1" / "params.json").write_text(json.dumps({"max_correspondence_distance": "far"}))
        (files / "suite" / "c1" / "init.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
        np.save(files / "suite" / "c1" / "source.npy", CLOUD)
        np.save(files / "suite" / "c1" / "target.npy", CLOUD)
    rc, err = cli([a.replace("{t}", str(files)) for a in argv], capsys)
    assert rc == 2, err
    assert len(err) == 1 and "Traceback" not in err[0], err
    assert message in err[0], err


def test_classification_resumes_and_writes_strict_json(tmp_path, capsys):
    argv = ["evaluate", "classification", "--data", "synthetic:syn1a", "--frames", "4", "--size", "48x36",
            "--trials", "2", "--cases", "I", "--features", "rgb", "--out", str(tmp_path)]
    rc, err = cli(argv, capsys)
    assert rc == 0, err
    units = sorted((tmp_path / "units").rglob("*.json"))
    assert units
    first = json.loads((tmp_path / "results.json").read_text())
    units[0].unlink()  # as if interrupted before this one finished
    rc, err = cli(argv, capsys)
    assert rc == 0, err
    again = json.loads((tmp_path / "results.json").read_text(), parse_constant=lambda c: pytest.fail(f"{c} in JSON"))
    assert [u["error"] for u in again["units"]] == [u["error"] for u in first["units"]]
    assert again["resumed_units"] == len(first["units"]) - 1


# ------------------------------------------------------------------------------------------------
# real subprocesses: special files, limits, stdout hygiene, locks
# ------------------------------------------------------------------------------------------------

def run(args, timeout=60, **kw):
    return subprocess.run([*PCREG, *map(str, args)], capture_output=True, text=True, timeout=timeout, **kw)


@pytest.mark.slow
def test_subprocess_fifo_and_bomb_end_in_bounded_memory(files):
    # each command runs under a one-child launcher that reports that child's peak memory alone (this test
    # process's own RUSAGE_CHILDREN also counts every command the suite ran before it)
    launcher = ("import resource, subprocess, sys\n"
                "r = subprocess.run(sys.argv[2:])\n"
                "open(sys.argv[1], 'w').write(str(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss))\n"
                "sys.exit(r.returncode)\n")
    for bad in ("fifo.png", "big30k.png", "big100k.png"):  # a FIFO with no writer must not block the read
        peak = files / f"{bad}.peak"
        p = subprocess.run([sys.executable, "-c", launcher, str(peak), *PCREG, "register", str(files / bad),
                            str(files / "good.png")], capture_output=True, text=True, timeout=HANG)
        assert p.returncode == 2 and len(p.stderr.strip().splitlines()) == 1, p.stderr
        assert "Traceback" not in p.stderr
        assert int(peak.read_text()) < 1_000_000, bad  # KiB: far below a decoded bomb


@pytest.mark.slow
def test_crosscheck_json_stays_parseable(files):
    """Open3D reports a damaged file only by printing (on stdout); it is refused with one line and
    stdout stays clean, and a good file gives JSON alone on stdout."""
    (files / "bad_token.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                                          b"property float y\nproperty float z\nend_header\n1 2 3\n4 5 x\n4 5 6\n")
    p = run(["crosscheck", files / "bad_token.ply", files / "ok.ply", "--json"], timeout=60)
    assert p.returncode == 2 and p.stdout == "", (p.stdout, p.stderr)
    assert len(p.stderr.strip().splitlines()) == 1 and "vertex line 2 ('4 5 x') is not 3 numbers" in p.stderr
    p = run(["crosscheck", files / "ok.ply", files / "ok.ply", "--json", "--iterations", "3"], timeout=120)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["kind"] == "clouds"


ROTATION = ["evaluate", "rotation", "--data", "synthetic:syn1a", "--frames", "2", "--size", "160x120",
            "--angles", "0,90", "--samples", "1"]  # 1 unit of 2 registrations: the run that follows the lock


def test_second_run_on_the_same_out_is_refused(tmp_path):
    """While another pcreg holds the folder's lock (here a process that holds it until told to stop),
    a run on it is refused at once with one line; once released, the run goes ahead."""
    out = tmp_path / "busy"
    holder = subprocess.Popen([sys.executable, "-c", "import sys\nfrom pcreg.outputs import OutputLock\n"
                               f"with OutputLock({str(out)!r}):\n    print('held', flush=True)\n    sys.stdin.read()\n"],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        p = run([*ROTATION, "--out", out], timeout=HANG)
        assert p.returncode == 2, p.stderr
        lines = p.stderr.strip().splitlines()
        assert len(lines) == 1 and "in use by another pcreg run" in lines[0]
        assert f"pid {holder.pid}" in lines[0]
    finally:
        holder.stdin.close()
        holder.wait(timeout=HANG)
    assert holder.returncode == 0
    p = run([*ROTATION, "--out", out], timeout=HANG)  # released on exit: the folder can be used again
    assert p.returncode == 0, p.stderr


HOSTILE_VALUES = ["nan", "inf", "-inf", "-1", "0", "1e309", "abc", "", "99999999999999999999", "0x0", "1,nan",
                  "-5x-5", "::", "1:2", " "]


def _all_subcommands():
    import argparse

    from pcreg.cli import build_parser

    parser = build_parser()
    found = {}
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, p in a.choices.items():
                if name != "evaluate":
                    found[(name,)] = p
                    continue
                for b in p._actions:
                    if isinstance(b, argparse._SubParsersAction):
                        found.update({("evaluate", n2): p2 for n2, p2 in b.choices.items()})
    return parser, found


@pytest.mark.slow
def test_every_option_with_hostile_values(tmp_path, capsys, monkeypatch):
    """Every option of every command, given each hostile value: refused with one line and exit 2, or
    accepted and run (register, crosscheck on two small images) to exit 0 or 2 — never a traceback or
    an unexpected error. Evaluations are parsed and their config built, not run."""
    import importlib


    monkeypatch.chdir(tmp_path)  # an accepted value such as `--out nan` writes its file here
    cv2.imwrite(str(tmp_path / "a.png"), GOOD[:, :, ::-1])
    cv2.imwrite(str(tmp_path / "b.png"), np.roll(GOOD, 3, axis=1)[:, :, ::-1])
    parser, commands = _all_subcommands()
    positional = {"register": [tmp_path / "a.png", tmp_path / "b.png"],
                  "crosscheck": [tmp_path / "a.png", tmp_path / "b.png"], "view": [tmp_path / "none.rrd"]}
    bad = []
    for key, sub in sorted(commands.items()):
        for action in sub._actions:
            if not action.option_strings or action.nargs == 0 or action.dest == "help":
                continue
            for value in HOSTILE_VALUES:
                fast = ["--iterations", "3"] if key[0] in ("register", "crosscheck") else []  # the tested option comes last
                argv = [*key, *map(str, positional.get(key[0], [])), *fast, action.option_strings[0], value]
                if key[0] in ("evaluate", "demo", "run"):
                    try:
                        args = parser.parse_args(argv)
                    except SystemExit as exc:
                        err = capsys.readouterr().err.strip().splitlines()
                        if exc.code != 2 or len(err) != 1:
                            bad.append((argv, exc.code, err))
                        continue
                    module = importlib.import_module(args._module)
                    try:
                        if hasattr(module, "config_from_args"):
                            module.config_from_args(args)
                    except PcregError:
                        pass
                    except Exception as exc:  # noqa: BLE001 - reported below
                        bad.append((argv, type(exc).__name__, str(exc)[:80]))
                    continue
                rc, err = cli(argv, capsys)
                if rc not in (0, 2, 3) or (rc != 0 and len(err) != 1) or any("unexpected" in e for e in err):
                    bad.append((argv, rc, err[-2:]))
    assert not bad, bad[:5]


def test_one_odd_sized_frame_fails_only_its_own_pairs():
    """A clip with one frame of another size: the pairs that involve it fail with the reason; every other
    pair is scored (the clip is not dropped)."""
    from pcreg.datasets import Frame, synthetic
    from pcreg.pipeline import run_sequence

    frames = synthetic("syn1a", 8, 0, width=96, height=72)
    odd = frames[4]
    frames[4] = Frame(image=cv2.resize(np.asarray(odd.image), (90, 72)),
                      labels=cv2.resize(np.asarray(odd.labels), (90, 72), interpolation=cv2.INTER_NEAREST), name=odd.name)
    res = run_sequence(frames, k=1, fusion_frames=2)
    failed = {(f["reference"], f["moving"]): f["reason"] for f in res.failures}
    assert set(failed) == {(3, 4), (4, 5)}
    assert all(f"frame {odd.name} is 90x72 px" in r for r in failed.values())
    scored = {(p.reference, p.moving) for p in res.pairs}
    assert scored == {(1, 2), (2, 3), (5, 6), (6, 7)}
    # every pair after the fusion frames touching it (a clip of three, the last of another size): the note gives
    # the failures' reason, not that no pair's moving frame comes after the fusion frames
    res = run_sequence(frames[2:5], k=1, fusion_frames=2)
    assert not res.pairs and len(res.failures) == 1
    assert res.notes[-1] == f"no pair scored: 1 pair(s) failed, the first (1, 2): frame {odd.name} is 90x72 px, " \
        "the sequence's frames are 96x72"


def test_view_time_beyond_64_bits_is_bad_input():
    from pcreg.commands.view import _parse_time

    assert _parse_time("frame=3") == ("frame", 3)
    with pytest.raises(InputError, match="out of range"):
        _parse_time("frame=99999999999999999999")


def test_run_never_writes_over_its_inputs(tmp_path, capsys):
    """--out the frames' folder (or the truth's) is refused before anything is written; labels in
    colours are refused, a grey image saved in colour is read as grey."""
    frames = tmp_path / "frames"
    frames.mkdir()
    for i in range(3):
        cv2.imwrite(str(frames / f"f{i}.png"), np.roll(GOOD, 2 * i, axis=1))
    labels = np.zeros(GOOD.shape[:2], np.uint8)
    labels[32:] = 1
    cv2.imwrite(str(tmp_path / "key.png"), labels)
    before = {p.name: p.read_bytes() for p in frames.iterdir()}
    rc, err = cli(["run", frames, "--out", frames, "--labels", tmp_path / "key.png"], capsys)
    assert rc == 2 and len(err) == 1 and "would overwrite the input" in err[0], err
    assert {p.name: p.read_bytes() for p in frames.iterdir()} == before
    jpegs = tmp_path / "jpegs"  # frames of another format: its NAME.png would be a second frame NAME
    jpegs.mkdir()
    for i in range(3):
        cv2.imwrite(str(jpegs / f"f{i}.jpg"), np.roll(GOOD, 2 * i, axis=1))
    rc, err = cli(["run", jpegs, "--out", jpegs, "--labels", tmp_path / "key.png"], capsys)
    assert rc == 2 and len(err) == 1 and "is the frames' own folder" in err[0], err
    assert sorted(p.suffix for p in jpegs.iterdir()) == [".jpg"] * 3
    rc, err = cli(["run", frames, "--out", tmp_path / "o", "--labels", frames / "f0.png"], capsys)
    assert rc == 2 and "single-channel" in err[0], err
    assert not (tmp_path / "o").exists()
    cv2.imwrite(str(tmp_path / "key3.png"), np.dstack([labels] * 3))
    rc, err = cli(["run", frames, "--out", tmp_path / "o", "--labels", tmp_path / "key3.png"], capsys)
    assert rc == 0, err
    assert sorted(p.name for p in (tmp_path / "o").glob("f*.png")) == ["f0.png", "f1.png", "f2.png"]


def test_a_recording_path_that_is_not_utf8_leaves_no_file(files, tmp_path, capsys):
    bad = tmp_path / os.fsdecode(b"r\xff.rrd")
    rc, err = cli(["register", files / "good.png", files / "good.png", "--record", bad], capsys)
    assert rc == 2 and len(err) == 1 and "UTF-8" in err[0], err
    assert list(tmp_path.iterdir()) == []
