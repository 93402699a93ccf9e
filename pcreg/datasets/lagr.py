"""DARPA LAGR hand-labelled sets: ``frame001.mat`` ... with ``im_rgb`` and ``manual_human_labeling_mask``
stored transposed (640x480), as the thesis used them."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..errors import DatasetError
from .frame import Frame

LAGR_IMAGE = "im_rgb"
LAGR_MASK = "manual_human_labeling_mask"


def _numbered(path: Path) -> tuple:
    m = re.search(r"(\d+)(?!.*\d)", path.stem)
    return (int(m.group(1)) if m else -1, path.name)


def _mat_frame(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    import scipy.io

    from ..errors import InputError
    from ..formats import check_regular_file, max_file_bytes
    from ..validation import max_pixels

    try:
        check_regular_file(path, what=".mat file")
    except InputError as exc:
        raise DatasetError(str(exc)) from None
    limit = max_pixels()
    if path.stat().st_size > max_file_bytes(limit):
        raise DatasetError(f"{path}: file too large for the pixel limit {limit} (raise --max-pixels)")
    try:
        # Shapes first, from the headers: a small compressed file can declare a huge array.
        for name, shape, _ in scipy.io.whosmat(str(path)):
            if name in (LAGR_IMAGE, LAGR_MASK) and int(np.prod(shape, dtype=np.float64)) > 3 * limit:
                raise DatasetError(f"{path}: {name} is {'x'.join(map(str, shape))}, over the pixel limit {limit} "
                                   "(raise --max-pixels)")
        mat = scipy.io.loadmat(str(path), variable_names=[LAGR_IMAGE, LAGR_MASK])
    except DatasetError:
        raise
    except Exception as exc:  # noqa: BLE001 - scipy raises several types on a damaged file
        raise DatasetError(f"{path}: cannot read .mat file ({type(exc).__name__}: {str(exc)[:200]})") from None
    if LAGR_IMAGE not in mat:
        raise DatasetError(f"{path}: no variable {LAGR_IMAGE!r} (has: {', '.join(sorted(k for k in mat if not k.startswith('__'))) or 'none'})")
    raw = np.asarray(mat[LAGR_IMAGE])
    if raw.ndim != 3 or raw.shape[2] != 3:
        raise DatasetError(f"{path}: {LAGR_IMAGE} must be W x H x 3, got {raw.shape}")
    if raw.size == 0:
        raise DatasetError(f"{path}: {LAGR_IMAGE} is {raw.shape[0]} x {raw.shape[1]} x 3: an empty image")
    image = np.ascontiguousarray(np.moveaxis(raw, 0, 1))
    if image.dtype.kind not in "biuf":
        raise DatasetError(f"{path}: {LAGR_IMAGE} must be numeric, got {image.dtype}")
    if image.dtype != np.uint8 and image.size and not np.all(np.isfinite(image)):
        raise DatasetError(f"{path}: {LAGR_IMAGE} has NaN or inf values")
    if image.dtype != np.uint8 and image.size and (image.min() < 0 or image.max() > 255):
        raise DatasetError(f"{path}: {LAGR_IMAGE} values {image.min():g}..{image.max():g} are outside 0..255")
    if image.dtype != np.uint8:
        if np.issubdtype(image.dtype, np.floating) and image.size and image.max() <= 1.0:
            image = image * 255.0
        image = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    mask = None
    if LAGR_MASK in mat:
        m = np.asarray(mat[LAGR_MASK])
        if m.dtype.kind not in "biuf":
            raise DatasetError(f"{path}: {LAGR_MASK} must be numeric, got {m.dtype}")
        if m.ndim != 2 or m.shape != raw.shape[:2]:
            raise DatasetError(f"{path}: {LAGR_MASK} is {m.shape}, expected {raw.shape[:2]} like {LAGR_IMAGE}")
        m = np.ascontiguousarray(np.moveaxis(m, 0, 1))
        if m.size and (not np.all(np.isfinite(m)) or np.any(m != np.rint(m)) or m.min() < 0 or m.max() > 2):
            bad = np.unique(m[(m < 0) | (m > 2) | (m != np.rint(m))])[:5]
            raise DatasetError(f"{path}: {LAGR_MASK} has values outside 0 ground, 1 obstacle, 2 unknown: {bad.tolist()}")
        mask = m.astype(np.uint8)
    return image, mask


def load_lagr(folder: str | Path) -> list[Frame]:
    """Load one LAGR set, e.g. ``labeled_lagr_data_640x480_DS1A/`` with ``frame001.mat`` ... .

    Each .mat holds ``im_rgb`` (W x H x 3, stored transposed) and ``manual_human_labeling_mask``
    (W x H); both are transposed back with ``np.moveaxis(a, 0, 1)``. A folder whose files have no mask
    (the supplemental frames) loads as unlabelled frames (``labels=None``); a folder where only some
    files have one is an error.

    Returns the frames in frame-number order (image (H, W, 3) uint8, labels (H, W) uint8 or None).
    """
    from ..validation import check_path

    folder = check_path(folder, "folder")
    if not folder.is_dir():
        raise DatasetError(f"{folder}: not a folder")
    files = sorted(folder.glob("*.mat"), key=_numbered)
    if not files:
        raise DatasetError(f"{folder}: no .mat frames")
    loaded = [(_mat_frame(p), p) for p in files]
    with_mask = [p for (_, m), p in loaded if m is not None]
    if with_mask and len(with_mask) != len(files):
        missing = next(p for (_, m), p in loaded if m is None)
        raise DatasetError(f"{missing}: no variable {LAGR_MASK!r} while other frames of {folder.name} have one")
    return [Frame(image=im, labels=m, name=p.stem) for (im, m), p in loaded]
