"""What the DAVIS tests share: small synthetic sequences written in pcreg's layout or the official one."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from PIL import Image


def frames_and_masks(n: int = 5, shape=(48, 64), seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` (BGR image, 0/255 mask) pairs: a lighter textured disc moving 2 px right a frame (its texture with it) over a textured ground."""
    h, w = shape
    rng = np.random.default_rng(seed)
    ground = cv2.GaussianBlur(rng.integers(0, 200, (h, w + 2 * n, 3), dtype=np.uint8), (0, 0), 1.0)
    out = []
    for i in range(n):
        mask = np.zeros((h, w), np.uint8)
        cv2.circle(mask, (w // 3 + 2 * i, h // 2), h // 5, 255, -1)
        img = np.ascontiguousarray(ground[:, :w])
        moved = ground[:, 2 * n - 2 * i:2 * n - 2 * i + w].astype(np.int16) + 50  # the disc's own texture, lighter
        img[mask > 0] = np.clip(moved, 0, 255).astype(np.uint8)[mask > 0]
        out.append((img, mask))
    return out


def write_pcreg_layout(seq: Path, pairs) -> Path:
    """``seq/images/NNNNN.jpg`` and ``seq/labels/NNNNN.png``."""
    (seq / "images").mkdir(parents=True)
    (seq / "labels").mkdir()
    for i, (img, mask) in enumerate(pairs):
        cv2.imwrite(str(seq / "images" / f"{i:05d}.jpg"), img)
        cv2.imwrite(str(seq / "labels" / f"{i:05d}.png"), mask)
    return seq


def write_official_layout(root: Path, name: str, pairs, resolution: str = "480p") -> Path:
    """``root/JPEGImages/RES/name/NNNNN.jpg`` and ``root/Annotations/RES/name/NNNNN.png``; returns root."""
    img_dir, ann_dir = root / "JPEGImages" / resolution / name, root / "Annotations" / resolution / name
    img_dir.mkdir(parents=True)
    ann_dir.mkdir(parents=True)
    for i, (img, mask) in enumerate(pairs):
        cv2.imwrite(str(img_dir / f"{i:05d}.jpg"), img)
        cv2.imwrite(str(ann_dir / f"{i:05d}.png"), mask)
    return root


def shared_sequence(shared_data: Path, name: str) -> Path:
    """``../shared/data/davis/NAME``, or the test skipped saying it is absent."""
    import pytest

    seq = shared_data / "davis" / name
    if not seq.is_dir():
        pytest.skip(f"{seq} is absent")
    return seq


#: DAVIS's palette: index 1 dark red, 2 dark green, 255 (void) white.
_PALETTE = [0, 0, 0, 128, 0, 0, 0, 128, 0] + [0, 0, 0] * 252 + [255, 255, 255]


def write_palette(path: Path, ids: np.ndarray) -> Path:
    im = Image.fromarray(ids.astype(np.uint8), mode="P")
    im.putpalette(_PALETTE)
    im.save(path)
    return path


def halves(mask: np.ndarray, *, void: bool = False) -> np.ndarray:
    """A one-object mask split into two objects: its left half index 1, its right half index 2 (and with
    ``void`` a band of 255 along the image's top rows)."""
    ids = np.zeros(mask.shape, np.uint8)
    cols = np.nonzero((mask > 0).any(axis=0))[0]
    mid = (cols.min() + cols.max() + 1) // 2 if cols.size else mask.shape[1] // 2
    obj = mask > 0
    ids[:, :mid][obj[:, :mid]] = 1
    ids[:, mid:][obj[:, mid:]] = 2
    if void:
        ids[:2] = 255
    return ids
