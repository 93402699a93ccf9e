"""A run's running error against the truth (``pcreg run --truth``): the counts run.json keeps, whole and
per key-frame stretch, and the check of the truth maps themselves."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .state import TRUTH_COUNTS

__all__ = ["empty_counts", "count_frame", "add_rates", "check_truth", "scored_step"]


def empty_counts() -> dict:
    """No frame counted yet."""
    return {k: 0 for k in TRUTH_COUNTS}


def count_frame(counts: dict, labels: np.ndarray, truth: np.ndarray, plain: np.ndarray | None, *,
                unknown: int = 2) -> None:
    """Add one frame to ``counts`` (in place): its pixels of known truth (``truth`` not ``unknown``, the
    class table's unknown id), how many of them ``labels`` has wrong, and how many naive Bayes alone
    (``plain``, when given) has wrong. A frame whose truth is all unknown is not counted: no pixel of it is scored."""
    known = truth != unknown
    if not known.any():
        return
    counts["frames"] += 1
    counts["wrong"] += int(np.count_nonzero(labels[known] != truth[known]))
    counts["known"] += int(known.sum())
    if plain is not None:
        counts["plain_wrong"] += int(np.count_nonzero(plain[known] != truth[known]))


def add_rates(counts: dict) -> dict:
    """``counts`` with its error rates in % (``error``, ``plain_error``; None before a known pixel)."""
    counts["error"] = 100.0 * counts["wrong"] / counts["known"] if counts["known"] else None
    counts["plain_error"] = 100.0 * counts["plain_wrong"] / counts["known"] if counts["known"] else None
    return counts


def scored_step(labels: np.ndarray, truth: np.ndarray, plain: np.ndarray | None, table=None) -> dict:
    """What a step's line keeps of frame's ``truth`` (ids of ``table``, a :class:`~pcreg.classes.ClassTable`;
    None: ``lagr``): ``error``, the % of its pixels of known truth that ``labels`` has wrong, ``plain_error`` the
    same of naive Bayes alone (``plain``, when given), and ``iou``, each known class's IoU (by class id, a string
    as JSON keeps it) for the classes that the truth or the labels hold there (none when no pixel is scored)."""
    from ..classification.metrics import class_iou, confusion_matrix, error_from_confusion, error_rate

    conf = confusion_matrix(labels, truth, classes=table)
    step: dict = {"error": error_from_confusion(conf)}
    if plain is not None:
        step["plain_error"] = error_rate(plain, truth, classes=table)
    known = {0, 1} if table is None else set(table.known_ids)
    iou = {str(c): v for c, v in class_iou(conf).items() if c in known}
    if iou:
        step["iou"] = iou
    return step


def check_truth(truth: list[np.ndarray | None], shape: tuple[int, int], names: list[str]) -> None:
    """Every truth map present and of the frames' size, or one line naming the first that is not by its file
    (``names``)."""
    for lab, name in zip(truth, names):
        if lab is None:
            raise InputError(f"{name}: no truth labels")
        if lab.shape != shape:
            raise InputError(f"{name}: truth labels of {lab.shape[1]}x{lab.shape[0]}, the frames "
                             f"{shape[1]}x{shape[0]}")
