"""Property-based fuzzing of every file loader: random bytes and mutated real files as PNG, JPEG, PLY,
PCD (an organised one too), NPY, text columns (CSV, TXT) and MAT. A loader returns a valid result or raises
PcregError; nothing else, and never hangs."""

from __future__ import annotations

import io
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import scipy.io
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pcreg.errors import PcregError

from _fuzz import bounded, mutated_bytes

FUZZ = settings(max_examples=30, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _seeds() -> dict[str, bytes]:
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    img[8:16, 8:24] = 255
    out = {"png": cv2.imencode(".png", img)[1].tobytes(), "jpg": cv2.imencode(".jpg", img)[1].tobytes()}
    pts = rng.normal(size=(40, 3)).astype("<f4")
    head = "ply\nformat {} 1.0\nelement vertex 40\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    out["ply"] = head.format("binary_little_endian").encode() + pts.tobytes()
    out["ply_ascii"] = (head.format("ascii") + "".join(f"{a:.4f} {b:.4f} {c:.4f}\n" for a, b, c in pts)).encode()
    pcd_head = ("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 40\nHEIGHT 1\n"
                "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 40\nDATA {}\n")
    out["pcd"] = pcd_head.format("binary").encode() + pts.tobytes()
    out["pcd_ascii"] = (pcd_head.format("ascii") + "".join(f"{a} {b} {c}\n" for a, b, c in pts)).encode()
    organised = pcd_head.replace("WIDTH 40\nHEIGHT 1", "WIDTH 8\nHEIGHT 5").format("ascii")
    out["pcd_organised"] = (organised + "".join("nan nan nan\n" if i % 7 == 3 else f"{a} {b} {c}\n"
                                                for i, (a, b, c) in enumerate(pts))).encode()
    normals = rng.normal(size=(40, 3))
    out["csv"] = ("x,y,z,nx,ny,nz\n" + "".join(f"{a} , {b} , {c} , {d},{e},{f}\n"
                                               for (a, b, c), (d, e, f) in zip(pts, normals))).encode()
    out["txt"] = "".join(f"{a:.18e} {b:.18e}\n" for a, b in pts[:, :2]).encode()
    buf = io.BytesIO()
    np.save(buf, pts.astype(np.float64))
    out["npy"] = buf.getvalue()
    buf = io.BytesIO()
    scipy.io.savemat(buf, {"im_rgb": np.moveaxis(img, 0, 1), "manual_human_labeling_mask":
                           rng.integers(0, 3, (32, 24)).astype(np.uint8)}, do_compression=False)
    out["mat"] = buf.getvalue()
    buf = io.BytesIO()
    scipy.io.savemat(buf, {"im_rgb": np.moveaxis(img, 0, 1)}, do_compression=True)
    out["mat_compressed"] = buf.getvalue()
    return out


SEEDS = _seeds()
SUFFIX = {"png": ".png", "jpg": ".jpg", "ply": ".ply", "ply_ascii": ".ply", "pcd": ".pcd", "pcd_ascii": ".pcd",
          "pcd_organised": ".pcd", "csv": ".csv", "txt": ".txt", "npy": ".npy", "mat": ".mat", "mat_compressed": ".mat"}


def _load(kind: str, path: Path):
    if kind in ("png", "jpg"):
        from pcreg.errors import ImageWarning
        from pcreg.registration.clouds import load_image

        with warnings.catch_warnings():  # a damaged JPEG is read and warned of (pcreg.errors.ImageWarning)
            warnings.simplefilter("ignore", ImageWarning)
            img = load_image(path)
        assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
        return img
    if kind.startswith(("ply", "pcd", "npy", "csv", "txt")):
        from pcreg.implementations.crosscheck import load_cloud

        pts = load_cloud(path)
        assert pts.ndim == 2 and np.all(np.isfinite(pts))
        return pts
    from pcreg.datasets import load_lagr

    frames = load_lagr(path.parent)
    assert frames[0].image.dtype == np.uint8
    return frames


def _check(kind: str, data: bytes, folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.iterdir():
        old.unlink()
    path = folder / f"frame001{SUFFIX[kind]}"
    path.write_bytes(data)
    with bounded():
        try:
            _load(kind, path)
        except PcregError as exc:
            assert str(exc) and "\n" not in str(exc)


def test_seeds_load():
    """The unmutated files are valid: the fuzzing starts from real, loadable files."""
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        for kind in SEEDS:
            folder = Path(d) / kind
            folder.mkdir()
            path = folder / f"frame001{SUFFIX[kind]}"
            path.write_bytes(SEEDS[kind])
            _load(kind, path)


@pytest.mark.parametrize("kind", sorted(SEEDS))
@FUZZ
@given(data=st.data())
def test_mutated_files(tmp_path_factory, kind, data):
    _check(kind, data.draw(mutated_bytes(SEEDS[kind])), tmp_path_factory.getbasetemp() / f"fuzz_{kind}")


@pytest.mark.parametrize("kind", ["png", "ply", "pcd", "npy", "mat"])
@FUZZ
@given(blob=st.binary(max_size=512))
def test_random_bytes(tmp_path_factory, kind, blob):
    _check(kind, blob, tmp_path_factory.getbasetemp() / f"rand_{kind}")


@pytest.mark.parametrize("kind", ["png", "ply", "pcd", "npy", "mat"])
@FUZZ
@given(blob=st.binary(max_size=256))
def test_real_header_then_random_bytes(tmp_path_factory, kind, blob):
    seed = SEEDS[kind]
    _check(kind, seed[: min(len(seed), 128)] + blob, tmp_path_factory.getbasetemp() / f"head_{kind}")
