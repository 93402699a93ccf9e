"""What naive Bayes and the thesis's weight search share: the training pairs checked, GaussianNB's parameters from
per-class histograms, and the log-likelihood tables of every 8-bit value, of Gaussians or of smoothed histograms
(their constants read from :mod:`pcreg.classification.bayes` too)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..classes import DEFAULT_TABLE, ClassTable
from ..errors import InputError
from .features import check_image

_LEVELS = np.arange(256, dtype=np.float64)
#: The smoothed histogram's Gaussian kernel (8-bit levels): chosen between 2 and 3 with each CamVid clip
#: left out (docs/results.md, "Many classes"); 4 and 8 were worse on all eight clips.
HISTOGRAM_BANDWIDTH = 2.0
#: The share of a uniform density mixed into each smoothed histogram, so that a level no training pixel
#: had is unlikely, never impossible (log 0).
HISTOGRAM_UNIFORM = 0.01


def _as_lists(images, labels, table: ClassTable = DEFAULT_TABLE) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Accept one image/label pair or sequences of them; check shapes, dtypes and label values (each a
    class id of ``table``)."""
    if isinstance(images, np.ndarray) and images.ndim == 3:
        images = [images]
    if isinstance(labels, np.ndarray) and labels.ndim == 2:
        labels = [labels]
    try:
        images = list(images)
        labels = list(labels)
    except TypeError:
        raise InputError("images and labels must be arrays or sequences of arrays") from None
    if len(images) != len(labels):
        raise InputError(f"{len(images)} images but {len(labels)} label arrays")
    if not images:
        raise InputError("no training images")
    out_i, out_l = [], []
    for k, (im, lab) in enumerate(zip(images, labels)):
        im = check_image(im)
        if lab is None:
            raise InputError(f"training image {k} has no labels")
        lab = np.asarray(lab)
        if lab.shape != im.shape[:2]:
            raise InputError(f"labels {lab.shape} do not match image {im.shape[:2]} (training pair {k})")
        if lab.dtype != np.uint8:
            if not np.issubdtype(lab.dtype, np.integer):
                raise InputError(f"labels must be integers, got {lab.dtype} (training pair {k})")
            if lab.size and (lab.min() < 0 or lab.max() > 255):
                raise InputError(f"label values outside 0..255 in training pair {k}")
            lab = lab.astype(np.uint8)
        if lab.size and (lab.max() >= table.n_values or not table.valid()[np.unique(lab)].all()):
            bad = next(int(v) for v in np.unique(lab) if not table.valid()[v])
            raise InputError(f"label values must be {table.describe()}; got {bad} in training pair {k}")
        out_i.append(im)
        out_l.append(lab)
    return out_i, out_l


def _gaussian_params(counts: np.ndarray, classes: np.ndarray, *, var_smoothing: float,
                     priors: Sequence[float] | None) -> dict:
    """GaussianNB's fitted parameters from (N, F, 256) histograms (scikit-learn's definitions)."""
    h = counts[classes].astype(np.float64)  # (n, F, 256)
    n_c = h[:, 0, :].sum(axis=1)  # (n,)
    theta = (h * _LEVELS).sum(axis=2) / n_c[:, None]
    var = (h * (_LEVELS[None, None, :] - theta[:, :, None]) ** 2).sum(axis=2) / n_c[:, None]
    total = h.sum(axis=0)  # (F, 256) over the trained classes = the training matrix X
    n = total[0].sum()
    mu_all = (total * _LEVELS).sum(axis=1) / n
    var_all = (total * (_LEVELS[None, :] - mu_all[:, None]) ** 2).sum(axis=1) / n
    # scikit-learn's epsilon, but never under var_smoothing grey levels squared: features that are all
    # constant (black frames) would otherwise have no variance at all, and no finite likelihood
    epsilon = var_smoothing * max(float(var_all.max()), 1.0)
    var = var + epsilon
    if priors is None:
        prior = n_c / n_c.sum()
    else:
        prior = np.asarray(priors, dtype=np.float64).reshape(-1)
        if prior.shape != n_c.shape or np.any(prior < 0) or not np.isclose(prior.sum(), 1.0):
            raise InputError(f"priors must be {len(n_c)} non-negative numbers summing to 1")
    return {"class_count": n_c, "theta": theta, "var": var, "epsilon": epsilon, "prior": prior}


def _tables(theta: np.ndarray, var: np.ndarray) -> np.ndarray:
    """(n, F, 256) float64: log N(v; theta, var) for every class, feature and 8-bit value v."""
    return -0.5 * np.log(2.0 * np.pi * var)[:, :, None] - 0.5 * (
        (_LEVELS[None, None, :] - theta[:, :, None]) ** 2 / var[:, :, None])


def _histogram_tables(counts: np.ndarray) -> np.ndarray:
    """(n, F, 256) float64: log of each class's and feature's histogram (``counts`` (n, F, 256)) smoothed by a
    Gaussian of :data:`HISTOGRAM_BANDWIDTH` levels, normalised, and mixed with
    :data:`HISTOGRAM_UNIFORM` of a uniform density."""
    from scipy.ndimage import gaussian_filter1d

    smooth = gaussian_filter1d(np.asarray(counts, np.float64), HISTOGRAM_BANDWIDTH, axis=2, mode="nearest")
    density = smooth / np.maximum(smooth.sum(axis=2, keepdims=True), 1e-300)
    return np.log((1.0 - HISTOGRAM_UNIFORM) * density + HISTOGRAM_UNIFORM / 256.0)
