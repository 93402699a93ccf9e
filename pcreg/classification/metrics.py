"""Per-pixel classification metrics: confusion matrices and error rates.

Labels follow pcreg's convention: 0 ground, 1 obstacle, 2 unknown. By default pixels whose *truth* is
unknown are left out of the score (the thesis scores only hand-labelled ground and obstacle pixels).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError

N_LABELS = 3
LABEL_NAMES = ("ground", "obstacle", "unknown")


def _check_pair(predicted: np.ndarray, truth: np.ndarray, mask: np.ndarray | None) -> tuple:
    from ..validation import check_unmasked

    for name, a in (("predicted labels", predicted), ("truth", truth), ("mask", mask)):
        check_unmasked(a, name)  # its masked values would be scored
    predicted = np.asarray(predicted)
    truth = np.asarray(truth)
    for name, a in (("predicted labels", predicted), ("truth", truth)):
        if not np.issubdtype(a.dtype, np.integer):
            raise InputError(f"{name} must be an integer array (0 ground, 1 obstacle, 2 unknown), got {a.dtype}")
    if predicted.shape != truth.shape:
        raise InputError(f"predicted labels {predicted.shape} and truth {truth.shape} differ in shape")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.dtype != np.bool_ and not (np.issubdtype(mask.dtype, np.integer) and np.isin(mask, (0, 1)).all()):
            raise InputError(f"mask must be a bool array (or of 0 and 1), got {mask.dtype}"
                             + (" holding other values" if np.issubdtype(mask.dtype, np.integer) else ""))
        mask = mask.astype(bool, copy=False)
        if mask.shape != truth.shape:
            raise InputError(f"mask {mask.shape} and truth {truth.shape} differ in shape")
    return predicted, truth, mask


def _check_ids(values: np.ndarray, table, what: str) -> None:
    """An :class:`InputError` when ``values`` (each in 0..N-1 of ``table``) hold one that is no class id of a table
    whose ids leave gaps (0, 5, 200): such a value would be counted as a class of its own."""
    if table is None or len(table.ids) == table.n_values or not values.size:
        return
    present = np.flatnonzero(np.bincount(values.astype(np.intp, copy=False), minlength=table.n_values))
    bad = present[~table.valid()[present]]
    if bad.size:
        raise InputError(f"{what} label {int(bad[0])} is not a class id ({table.describe()})")


def confusion_matrix(predicted: np.ndarray, truth: np.ndarray, *, mask: np.ndarray | None = None,
                     exclude_unknown: bool = True, classes=None) -> np.ndarray:
    """Pixel counts of (true label, predicted label).

    predicted, truth : (H, W) integer arrays with values in {0, 1, 2} (any equal shape works); with
        ``classes`` (a :class:`~pcreg.classes.ClassTable`, or what :func:`pcreg.classes.class_table` reads: a
        built-in's name or a file), its ids, N = ``classes.n_values``.
    mask : (H, W) bool, optional — only pixels where it is True are counted (e.g. the valid part of a
        warped image).
    exclude_unknown : leave out pixels whose truth is unknown (2, or ``classes.unknown``).

    Returns (N, N) int64 ((3, 3) by default), rows = truth, columns = prediction.
    """
    table = None
    if classes is not None:
        from ..classes import class_table

        table = class_table(classes)
    n_labels = N_LABELS if table is None else table.n_values
    unknown = 2 if table is None else table.unknown
    predicted, truth, mask = _check_pair(predicted, truth, mask)
    t = truth.reshape(-1)
    p = predicted.reshape(-1)
    if t.size and (int(t.max()) >= n_labels or int(t.min()) < 0):
        raise InputError(f"truth labels must be in 0..{n_labels - 1}")
    _check_ids(t, table, "truth")
    keep = t != unknown if exclude_unknown else np.ones(t.shape, bool)
    if mask is not None:
        keep &= mask.reshape(-1)
    if keep.all():
        t_k, p_k = t, p
    else:
        t_k, p_k = t[keep], p[keep]
    if p_k.size and (int(p_k.max()) >= n_labels or int(p_k.min()) < 0):
        raise InputError(f"predicted labels must be in 0..{n_labels - 1}")
    _check_ids(p_k, table, "predicted")
    counts = np.bincount(t_k.astype(np.intp) * n_labels + p_k.astype(np.intp), minlength=n_labels * n_labels)
    return counts.reshape(n_labels, n_labels).astype(np.int64)


def check_confidence(confidence, shape: tuple, name: str = "confidence") -> np.ndarray:
    """``confidence`` as a float32 array of ``shape`` (the labels'), each value the probability that a label is
    right, in [0, 1]; else an :class:`InputError` naming ``name``: a NaN, or a value outside [0, 1], would make
    every figure read from it (a predicted IoU, a calibration error) NaN, empty or out of its range."""
    c = np.asarray(confidence)
    if not (np.issubdtype(c.dtype, np.floating) or np.issubdtype(c.dtype, np.integer)) or c.dtype == np.bool_:
        raise InputError(f"{name} must be a float array of probabilities in [0, 1], got {c.dtype}")
    if c.shape != tuple(shape):
        raise InputError(f"{name} {c.shape} and the labels {tuple(shape)} differ in shape")
    c = c.astype(np.float32, copy=False)
    if c.size:
        lo, hi = float(c.min()), float(c.max())
        if not (np.isfinite(lo) and np.isfinite(hi)):
            raise InputError(f"{name} holds NaN or infinite values: no probability of a label being right")
        if lo < 0.0 or hi > 1.0:
            raise InputError(f"{name} holds {lo if lo < 0 else hi:g}: a probability is in [0, 1]")
    return c


def error_from_confusion(confusion: np.ndarray) -> float:
    """Error rate in percent from a square (N, N) confusion matrix; NaN when it counts no pixel."""
    confusion = np.asarray(confusion)
    total = int(confusion.sum())
    if total == 0:
        return float("nan")
    return 100.0 * (total - int(np.trace(confusion))) / total


def class_iou(conf: np.ndarray) -> dict[int, float]:
    """Each class's IoU of a (truth, label) confusion matrix (:func:`confusion_matrix`), for the classes that the
    truth or the labels have."""
    tp = np.diag(conf).astype(np.float64)
    union = conf.sum(0) + conf.sum(1) - tp
    return {int(c): float(tp[c] / union[c]) for c in np.flatnonzero(union)}


def error_rate(predicted: np.ndarray, truth: np.ndarray, *, mask: np.ndarray | None = None,
               exclude_unknown: bool = True, classes=None) -> float:
    """Percentage of scored pixels whose predicted label differs from the truth.

    predicted, truth : (H, W) integer arrays in {0, 1, 2} (with ``classes``, a
    :class:`~pcreg.classes.ClassTable` or a built-in table's name or a table's file, its ids); mask : (H, W) bool,
    optional.
    Returns a float in [0, 100]; NaN when no pixel is scored (all unknown or all masked out).
    """
    return error_from_confusion(confusion_matrix(predicted, truth, mask=mask, exclude_unknown=exclude_unknown,
                                                 classes=classes))
