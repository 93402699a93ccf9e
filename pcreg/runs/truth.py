"""A run's running error against the truth (``pcreg run --truth``): the counts run.json keeps, whole and
per key-frame stretch, and the check of the truth maps themselves."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from .state import TRUTH_COUNTS

__all__ = ["empty_counts", "count_frame", "add_rates", "check_truth"]


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


def check_truth(truth: list[np.ndarray | None], shape: tuple[int, int], names: list[str]) -> None:
    """Every truth map present and of the frames' size, or one line naming the first that is not by its file
    (``names``)."""
    for lab, name in zip(truth, names):
        if lab is None:
            raise InputError(f"{name}: no truth labels")
        if lab.shape != shape:
            raise InputError(f"{name}: truth labels of {lab.shape[1]}x{lab.shape[0]}, the frames "
                             f"{shape[1]}x{shape[0]}")
