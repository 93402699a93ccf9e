"""The thesis's random search for the weights of its single feature (its Sec. 4, Table 4.1), scored exactly from
each class's counts of distinct colours (:func:`colour_counts`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ._gaussian import _as_lists, _gaussian_params, _histogram_tables, _tables
from .features import normalise_weights
from .metrics import LABEL_NAMES, N_LABELS

__all__ = ["WeightSearch", "colour_counts", "thesis_weight_search"]


@dataclass(frozen=True)
class WeightSearch:
    """The thesis's random search for the weights of its single feature (its Table 4.1).

    weights : (w_r, w_g, w_b) with the lowest training error (sum 1).
    error : that training error, percent of training pixels (unknown excluded unless it was trained as a class).
    trial_weights : (n_trials, 3) float64; trial_errors : (n_trials,) float64 percent, NaN for a trial whose
        classifier cannot be fitted (``var_smoothing`` 0 and a class of one value of the feature).
    seed : the seed of the trial weights.
    """

    weights: tuple[float, float, float]
    error: float
    trial_weights: np.ndarray
    trial_errors: np.ndarray
    seed: int

    def __repr__(self) -> str:
        w = ", ".join(f"{v:.3f}" for v in self.weights)
        return f"WeightSearch(weights=({w}), error={self.error:.2f}%, trials={len(self.trial_errors)}, seed={self.seed})"

    def to_dict(self) -> dict:
        return {"weights": list(self.weights), "error": float(self.error),
                "trial_weights": self.trial_weights.tolist(),
                "trial_errors": [None if np.isnan(e) else float(e) for e in self.trial_errors],
                "seed": int(self.seed)}


def colour_counts(images, labels, *, exclude_unknown: bool = True) -> list[tuple[np.ndarray, np.ndarray]]:
    """For each label 0, 1, 2: the distinct colours of its pixels and how often each occurs.

    Returns a list of 3 pairs ``(colours (K, 3) uint8, counts (K,) int64)``; unknown's pair is empty
    when ``exclude_unknown``.
    """
    images, labels = _as_lists(images, labels)
    out = []
    for c in range(N_LABELS):
        if exclude_unknown and c == 2:
            out.append((np.zeros((0, 3), np.uint8), np.zeros(0, np.int64)))
            continue
        packed = []
        for im, lab in zip(images, labels):
            sel = im[lab == c].astype(np.int32)
            packed.append((sel[:, 0] << 16) | (sel[:, 1] << 8) | sel[:, 2])
        keys = np.concatenate(packed) if packed else np.zeros(0, np.int32)
        if keys.size == 0:
            out.append((np.zeros((0, 3), np.uint8), np.zeros(0, np.int64)))
            continue
        binc = np.bincount(keys, minlength=1 << 24)
        nz = np.flatnonzero(binc)
        colours = np.stack([(nz >> 16) & 255, (nz >> 8) & 255, nz & 255], axis=1).astype(np.uint8)
        out.append((colours, binc[nz].astype(np.int64)))
    return out


def thesis_weight_search(images, labels, *, n_trials: int = 30, seed: int = 0, exclude_unknown: bool = True,
                         var_smoothing: float = 1e-9) -> WeightSearch:
    """Pick (w_r, w_g, w_b) for the thesis feature by random search (thesis Sec. 4, Table 4.1).

    Draws ``n_trials`` weight triples uniformly from [0, 1)^3 (normalised to sum 1) with
    ``numpy.random.default_rng(seed)``, fits the single-feature classifier to the training frames for
    each, and keeps the triple with the lowest training error. Exact: each trial is scored from the
    per-class counts of distinct colours, which give the same histograms as the pixels themselves, with the
    model :class:`~pcreg.classification.bayes.NaiveBayesPixelClassifier` fits them to (its ``density="auto"``:
    a Gaussian per class with two classes, the smoothed histogram with more, as with ``exclude_unknown=False``
    and unknown pixels in the labels).

    images : (H, W, 3) uint8 or a sequence; labels : (H, W) uint8 or a sequence.
    var_smoothing : as :class:`NaiveBayesPixelClassifier`'s; at 0 a trial whose feature takes one value over a
        class is not one the classifier can fit (a Gaussian of no width): it is left out (error NaN), and
        an :class:`~pcreg.errors.InputError` says so when every trial is.
    """
    import cv2

    from ..validation import check_float, check_int

    n_trials = check_int(n_trials, "n_trials", lo=1, hi=1_000_000)
    seed = check_int(seed, "seed", lo=0)
    var_smoothing = check_float(var_smoothing, "var_smoothing", lo=0)
    counts = colour_counts(images, labels, exclude_unknown=exclude_unknown)
    present = [c for c in range(N_LABELS) if counts[c][1].size]
    if len(present) < 2:
        held = f"only one class ({LABEL_NAMES[present[0]]})" if present else "no class (every pixel unknown)"
        raise InputError(f"training labels hold {held}; need both ground and obstacle pixels")
    rng = np.random.default_rng(seed)
    raw = rng.random((n_trials, 3))
    trial_weights = np.array([normalise_weights(w.tolist() if w.sum() > 0 else [1.0, 1.0, 1.0]) for w in raw])
    errors = np.empty(n_trials)
    classes = np.array(present)
    for t, w in enumerate(trial_weights):
        hist = np.zeros((N_LABELS, 1, 256), dtype=np.int64)
        for c in present:
            colours, cnt = counts[c]
            v = cv2.transform(colours.reshape(-1, 1, 3), w.reshape(1, 3)).reshape(-1)
            hist[c, 0] = np.bincount(v, weights=cnt, minlength=256).astype(np.int64)
        p = _gaussian_params(hist, classes, var_smoothing=var_smoothing, priors=None)
        if len(classes) > 2:  # the classifier's density with more than two classes: each one's smoothed histogram
            tables = _histogram_tables(hist[classes])
        elif np.all(p["var"] > 0):
            tables = _tables(p["theta"], p["var"])
        else:  # var_smoothing 0 and a class of one value: the fit refuses these weights
            errors[t] = np.nan
            continue
        jll = tables[:, 0, :] + np.log(p["prior"])[:, None]  # (n, 256)
        winner = np.argmax(jll, axis=0)  # index into classes for each value
        h = hist[classes, 0, :]  # (n, 256)
        correct = h[winner, np.arange(256)].sum()
        errors[t] = 100.0 * (1.0 - correct / h.sum())
    if np.all(np.isnan(errors)):
        raise InputError("every trial's feature takes one value over a class and var_smoothing is 0: no Gaussian "
                         "can be fitted; give var_smoothing > 0 (the default is 1e-9)")
    best = int(np.nanargmin(errors))
    wb = trial_weights[best]
    return WeightSearch(weights=(float(wb[0]), float(wb[1]), float(wb[2])), error=float(errors[best]),
                        trial_weights=trial_weights, trial_errors=errors, seed=int(seed))
