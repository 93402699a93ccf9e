"""CamVid's 32 classes' colours read as ``camvid11``'s eleven (:data:`CAMVID32`, :func:`read_camvid_labels`): what
:mod:`pcreg.datasets.camvid` reads its download's labels with, and :mod:`pcreg.datasets.folder` a clip's
``NAME_L.png`` labels, each without reading the other. The grouping is :mod:`pcreg.datasets.camvid`'s (SegNet's)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..classes.camvid32 import CAMVID32
from ..errors import DatasetError, InputError

__all__ = ["CAMVID32", "camvid32_ids", "read_camvid_labels"]


def camvid32_ids(rgb: np.ndarray, where: str) -> np.ndarray:
    """(H, W) uint8 ``camvid11`` ids of an (H, W, 3) uint8 RGB label image in CamVid's 32 classes' colours
    (or ``camvid11``'s; :func:`pcreg.classes.camvid32.camvid32_ids`); a :class:`DatasetError` naming ``where`` and
    the first colour of neither."""
    from ..classes.camvid32 import camvid32_ids as ids_of

    try:
        return ids_of(rgb, where)
    except InputError as exc:
        raise DatasetError(str(exc)) from None


def read_camvid_labels(path: Path, table, mapping: str | None) -> np.ndarray:
    """(H, W) uint8 labels of ``table`` (``camvid11``, or ``lagr`` with ``mapping="camvid"``) of the label file at
    ``path``: as :func:`pcreg.classes.keys.read_key_labels` reads it, and else, when it is a colour image, in
    CamVid's 32 classes' colours grouped as ``camvid11``'s (:data:`CAMVID32`). What the key-label reader reads
    is read as it reads it."""
    from ..classes.keys import decode_key_labels
    from ..classes.mappings import mapping_lut
    from ..classes.png import is_palette_png
    from ..formats import RAISE_LIMIT, decode_image, max_file_bytes, read_regular_file
    from ..validation import max_pixels

    lim = max_pixels(None)
    try:
        data = read_regular_file(path, max_bytes=max_file_bytes(lim), what="image", hint=RAISE_LIMIT)
    except InputError as exc:
        raise DatasetError(str(exc)) from None
    try:
        return decode_key_labels(data, str(path), table, "none" if mapping is None else "camvid", limit=lim)
    except InputError as exc:
        first = DatasetError(str(exc))
    if is_palette_png(data):
        raise first from None
    try:
        img = decode_image(data, str(path), limit=lim)
    except InputError:
        raise first from None
    if img.ndim != 3 or img.dtype != np.uint8 or img.shape[2] not in (3, 4) \
            or (img.shape[2] == 4 and (img[:, :, 3] != 255).any()) or (img[:, :, 1:3] == img[:, :, :1]).all():
        raise first from None  # not colours: ids, or a grey image saved in colour
    ids = camvid32_ids(np.ascontiguousarray(img[:, :, 2::-1]), str(path))
    if mapping is None:
        return ids
    lut = mapping_lut("camvid")
    assert lut is not None
    return lut[ids]
