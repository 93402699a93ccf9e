"""Per-pixel Gaussian naive Bayes classifier over the classes of a class table (ground / obstacle / unknown
by default).

The model is scikit-learn's :class:`~sklearn.naive_bayes.GaussianNB` (same parameters, same
``var_smoothing`` rule, same log-posteriors), fitted and evaluated through the fact that every feature
of :mod:`pcreg.classification.features` is an 8-bit plane:

- *fit* accumulates, per class and feature, a 256-bin histogram of the training pixels; the class means
  and variances follow exactly from the histograms (no (N, F) matrix of millions of pixels is built);
- *predict* looks every plane up in a 256-entry table of per-class Gaussian log-likelihoods
  (``cv2.LUT``) and sums them, which is Eq. (log p(c) + sum_f log N(x_f; mu_cf, var_cf)) of
  Gaussian naive Bayes evaluated without a single exp or division per pixel.

Labels are class ids of a :class:`~pcreg.classes.ClassTable` (default :data:`~pcreg.classes.LAGR`: 0 ground,
1 obstacle, 2 unknown); the known classes present in the training labels are the model's classes, the
unknown left out. Two classes have a fast path (:meth:`NaiveBayesPixelClassifier.decision_function`, one
table of log-likelihood differences); K classes are scored per class
(:meth:`NaiveBayesPixelClassifier.class_scores`, :meth:`NaiveBayesPixelClassifier.log_posteriors`).

The thesis's weight search (30 random (w_r, w_g, w_b), lowest training error wins, its Table 4.1) is
:func:`pcreg.classification.weight_search.thesis_weight_search` (read here too, deprecated, until 0.4); it scores
each trial from per-class counts of distinct colours.
"""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from ..classes import DEFAULT_TABLE, ClassTable
from ..classes.table import listed_name
from ..errors import InputError
from .features import (
    DEFAULT_FEATURES,
    check_image,
    feature_groups,
    frame_features,
    table_sum,
    feature_names,
    normalise_weights,
    parse_features,
)
from ._gaussian import HISTOGRAM_BANDWIDTH, _as_lists, _gaussian_params, _histogram_tables, _tables
from .metrics import LABEL_NAMES, N_LABELS, confusion_matrix, error_from_confusion, error_rate  # noqa: F401

__all__ = [
    "NaiveBayesPixelClassifier",
    "DENSITIES",
    "HISTOGRAM_BANDWIDTH",
    "DEGENERATE_VARIANCE",
    "class_histograms",
    "error_rate",
    "confusion_matrix",
    "error_from_confusion",
]

def class_histograms(images, labels, features: str | Iterable[str] = DEFAULT_FEATURES, *,
                     weights: Sequence[float] | None = None, exclude_unknown: bool = True,
                     classes: ClassTable | None = None) -> np.ndarray:
    """Per-class, per-feature histograms of the training pixels.

    images : (H, W, 3) uint8 or a sequence of them; labels : (H, W) uint8 class ids of ``classes`` (default
    :data:`~pcreg.classes.LAGR`, 0 ground, 1 obstacle, 2 unknown) or a sequence.
    Returns (N, F, 256) int64, N = ``classes.n_values`` (3 by default): ``counts[c, f, v]`` = number of
    pixels of label c whose feature f is v (the unknown's row stays zero when ``exclude_unknown``).
    """
    table = DEFAULT_TABLE if classes is None else classes
    images, labels = _as_lists(images, labels, table)
    names = parse_features(features)
    n_feat = len(feature_names(names))
    n_labels = table.n_values
    counts = np.zeros((n_labels, n_feat, 256), dtype=np.int64)
    counted = [c for c in table.ids if not (exclude_unknown and c == table.unknown)]
    for im, lab in zip(images, labels):
        lab_flat = lab.reshape(-1)
        keep = lab_flat != table.unknown if exclude_unknown else np.ones(lab_flat.shape, bool)
        all_kept = bool(keep.all())
        lab_k = (lab_flat if all_kept else lab_flat[keep]).astype(np.intp) * 256
        f = 0
        for name, planes in feature_groups(im, names, weights=weights):
            if name == "row":
                # one value per row: count labels per row, then add the rows' counts to their levels
                h, w = lab.shape
                per_row = np.zeros((n_labels, h), dtype=np.int64)
                for c in counted:
                    per_row[c] = np.count_nonzero(lab == c, axis=1)
                for c in counted:
                    counts[c, f] += np.bincount(planes, weights=per_row[c], minlength=256).astype(np.int64)
                f += 1
                continue
            flat = planes.reshape(-1, planes.shape[-1])
            for j in range(flat.shape[1]):
                col = flat[:, j] if all_kept else flat[keep, j]
                counts[:, f] += np.bincount(lab_k + col, minlength=n_labels * 256).reshape(n_labels, 256)
                f += 1
    return counts


def fit_classifier(frames: Sequence, *, features: Sequence[str] = DEFAULT_FEATURES,
                   classes: ClassTable | str | None = None) -> "NaiveBayesPixelClassifier":
    """A :class:`NaiveBayesPixelClassifier` fitted on labelled frames (objects with ``image`` and
    ``labels``, such as :class:`pcreg.datasets.Frame`), labels the ids of ``classes`` (a
    :class:`~pcreg.classes.ClassTable` or what :func:`pcreg.classes.class_table` reads; default ``lagr``);
    unknown pixels are left out, and every known class with training pixels is a class of the model."""
    from ..validation import check_frames

    check_frames(frames, "frames", labelled=True)
    return NaiveBayesPixelClassifier(features, classes=classes).fit([f.image for f in frames], [f.labels for f in frames])


#: How a class's feature density is modelled (:class:`NaiveBayesPixelClassifier`'s ``density``): ``"auto"``
#: (a Gaussian with two classes, a smoothed histogram with more), ``"gaussian"`` or ``"histogram"``.
DENSITIES: tuple[str, ...] = ("auto", "gaussian", "histogram")
#: A class whose training pixels vary less than this (8-bit levels squared; 1/12, the variance of the 8-bit
#: rounding itself) in every feature is one point of the features' space, fitted as a spike narrower than a
#: level: its log-likelihoods elsewhere are set by ``var_smoothing`` alone (a key frame of one class and a
#: single pixel of another read every later pixel with log-odds of -1e5 to -1e9, and a confidence of 1). One
#: colour feature alone is not enough to say so: an overexposed sky of 13,635 px has a hue variance of 0.014. The
#: image row is, with the Gaussian density: a class under it in the ``row`` feature lies on one row (a scribble
#: along a facade), and every pixel of every other row, whatever its colour, reads as not that class with
#: log-odds of 1e5 and more (the next CamVid frame labelled 23% right with a predicted error of 0%). The smoothed
#: histogram, never 0 in any bin, keeps such a class a class (eleven CamVid classes, a pole's 4 px on one row: the next
#: frame 94.1% right at a mean confidence of 0.963).
DEGENERATE_VARIANCE = 1.0 / 12.0


class NaiveBayesPixelClassifier:
    """Naive Bayes over per-pixel features, with scikit-learn's conventions: Gaussian (scikit-learn's
    GaussianNB) with two classes; with more, each class's density of each feature is its training
    histogram smoothed (``density``).

    Parameters
    ----------
    features : names from :data:`pcreg.classification.features.FEATURES` (``"thesis"``, ``"rgb"``, ``"hsv"``,
        ``"lab"``, ``"texture"``, ``"row"``), a tuple or a ``"rgb+hsv+row"`` string.
    weights : (w_r, w_g, w_b) of the ``"thesis"`` feature (normalised to sum 1; default equal).
    exclude_unknown : leave the unknown's pixels (label 2 by default) out of training (the default, as in
        the thesis); with False, unknown is one more class.
    var_smoothing : as scikit-learn's GaussianNB: ``var_smoothing * max feature variance`` is added to
        every variance.
    priors : class priors in the order of ``classes_``; default: training frequencies.
    classes : the class table of the labels (:func:`pcreg.classes.class_table`: a table, a built-in's name
        or a file; default ``lagr``, 0 ground, 1 obstacle, 2 unknown).
    density : :data:`DENSITIES`: ``"auto"`` (default) models each class's feature as a Gaussian when two
        classes are trained and as its histogram smoothed by :data:`HISTOGRAM_BANDWIDTH` levels when more
        are (buildings, trees or roads are rarely one Gaussian of colour); ``"gaussian"`` or
        ``"histogram"`` choose one whatever the classes.

    Fitted attributes (scikit-learn's names): ``classes_`` (n,) uint8, the ids of the classes with training
    pixels, ascending; ``class_count_`` (n,), ``class_prior_`` (n,), ``theta_`` (n, F), ``var_`` (n, F),
    ``epsilon_``, ``counts_`` (N, F, 256) histograms (N = ``class_table.n_values``, 3 by default),
    ``feature_names_`` (F,).
    """

    def __init__(self, features: str | Iterable[str] = DEFAULT_FEATURES, *,
                 weights: Sequence[float] | None = None, exclude_unknown: bool = True,
                 var_smoothing: float = 1e-9, priors: Sequence[float] | None = None,
                 classes: ClassTable | str | None = None, density: str = "auto") -> None:
        from ..classes import class_table
        from ..validation import check_bool, check_float, short_repr

        self.class_table = class_table(classes)
        self.features = parse_features(features)
        self.weights = normalise_weights(weights)
        self.exclude_unknown = check_bool(exclude_unknown, "exclude_unknown")

        self.var_smoothing = check_float(var_smoothing, "var_smoothing", lo=0)
        if priors is not None:
            try:
                priors = tuple(float(p) for p in priors)
            except (TypeError, ValueError):
                raise InputError(f"priors must be numbers, got {short_repr(priors)}") from None
            if not all(np.isfinite(p) and p >= 0 for p in priors) or abs(sum(priors) - 1) > 1e-6:
                raise InputError(f"priors must be finite, >= 0 and sum to 1, got {priors}")
        self.priors = priors
        if not isinstance(density, str) or density not in DENSITIES:
            raise InputError(f"unknown density {short_repr(density)}; choose one of {', '.join(DENSITIES)}")
        self.density = density
        self.feature_names_ = feature_names(self.features)

    def __repr__(self) -> str:
        w = "" if "thesis" not in self.features else f", weights=({', '.join(f'{v:.3f}' for v in self.weights)})"
        fitted = "" if not hasattr(self, "classes_") else f", classes={[self.class_table.name_of(c) for c in self.classes_]}"
        density = "" if self.density == "auto" else f", density={self.density!r}"
        return (f"NaiveBayesPixelClassifier(features={'+'.join(self.features)}{w}, "
                f"exclude_unknown={self.exclude_unknown}{density}{fitted})")

    def unfitted(self) -> "NaiveBayesPixelClassifier":
        """A new classifier with this one's options (features, weights, unknown, smoothing, priors, class table,
        density), not fitted: what learning refits from its histograms."""
        return type(self)(self.features, weights=self.weights, exclude_unknown=self.exclude_unknown,
                          var_smoothing=self.var_smoothing, priors=self.priors, classes=self.class_table,
                          density=self.density)

    # -- fitting -------------------------------------------------------------------------------
    def fit(self, images, labels) -> "NaiveBayesPixelClassifier":
        """Fit on one (H, W, 3) uint8 image and (H, W) uint8 labels, or on sequences of them.

        Raises :class:`~pcreg.errors.InputError` when fewer than two classes have training pixels.
        """
        counts = class_histograms(images, labels, self.features, weights=self.weights,
                                  exclude_unknown=self.exclude_unknown, classes=self.class_table)
        return self.fit_histograms(counts)

    def fit_histograms(self, counts: np.ndarray) -> "NaiveBayesPixelClassifier":
        """Fit from :func:`class_histograms` output, (N, F, 256) int (histograms of several training
        sets can be summed first)."""
        counts = np.asarray(counts)
        n_feat = len(self.feature_names_)
        table = self.class_table
        if counts.shape != (table.n_values, n_feat, 256):
            raise InputError(f"histograms must be ({table.n_values}, {n_feat}, 256), got {counts.shape}")
        if counts.dtype.kind not in "biuf" or not np.isfinite(counts).all() or (counts < 0).any():
            raise InputError(f"histograms must be counts of pixels (finite numbers, none below 0), got "
                             f"{'values of ' + str(counts.dtype) if counts.dtype.kind not in 'biuf' else 'NaN, inf or negative counts'}")
        if self.exclude_unknown and counts[table.unknown].any():
            raise InputError("histograms count unknown pixels but exclude_unknown is set")
        present = counts[:, 0, :].sum(axis=1) > 0
        classes = np.flatnonzero(present).astype(np.uint8)
        if len(classes) < 2:
            held = f"only one class ({listed_name(table.name_of(int(classes[0])))})" if len(classes) else \
                f"no class (every pixel {listed_name(table.unknown_class.name)})"
            need = "both ground and obstacle" if table.agrees(DEFAULT_TABLE) else "at least two classes'"
            raise InputError(f"training labels hold {held}; need {need} pixels")
        p = _gaussian_params(counts, classes, var_smoothing=self.var_smoothing, priors=self.priors)
        histogram = self.density == "histogram" or (self.density == "auto" and len(classes) > 2)
        if not histogram and not np.all(p["var"] > 0):  # var_smoothing 0: a Gaussian of no width, NaN tables
            c, f = np.argwhere(~(p["var"] > 0))[0]
            raise InputError(f"class {listed_name(table.name_of(int(classes[c])))} has no variance in feature "
                             f"{self.feature_names_[f]!r} (every training pixel of it the same value) and var_smoothing "
                             "is 0: give var_smoothing > 0 (the default is 1e-9), or density='histogram'")
        self.counts_ = counts.astype(np.int64, copy=True)
        self.classes_ = classes
        self.class_count_ = p["class_count"]
        self.class_prior_ = p["prior"]
        self.theta_ = p["theta"]
        self.var_ = p["var"]
        self.epsilon_ = p["epsilon"]
        tables = _histogram_tables(counts[classes]) if histogram else _tables(self.theta_, self.var_)  # (n, F, 256)
        self._tables64 = tables
        with np.errstate(divide="ignore"):  # a prior of 0 given on purpose: that class is never chosen
            self._log_prior = np.log(self.class_prior_)
        # Fast path: for two classes, the decision is sign(sum_f D_f[x_f] + log p1 - log p0).
        self._diff32 = (tables[1] - tables[0]).astype(np.float32) if len(classes) == 2 else None
        self._tables32 = tables.astype(np.float32)
        return self

    def in_lagr_ids(self) -> "NaiveBayesPixelClassifier":
        """This fitted classifier of two known classes in other ids (:func:`pcreg.classes.keys.lagr_ids`) refitted from
        its histograms in ``lagr``'s: the classifier of the same labels coded 0, 1 and 2, what the two-class step runs."""
        from ..classes.keys import lagr_ids

        ids = lagr_ids(self.class_table)
        if ids is None or not hasattr(self, "counts_"):
            raise InputError(f"in_lagr_ids needs a classifier fitted on two known classes in other ids than 0, 1 "
                             f"and 2, not {self.class_table.describe()}")
        return type(self)(self.features, weights=self.weights, exclude_unknown=self.exclude_unknown, priors=self.priors,
                          var_smoothing=self.var_smoothing, density=self.density).fit_histograms(self.counts_[ids])

    def degenerate_classes(self) -> list[int]:
        """The ids of the fitted classes whose training pixels vary less than :data:`DEGENERATE_VARIANCE` in
        every feature (a class of one pixel, always), or, with the Gaussian density, in the ``row`` feature (a
        class on one row): the model cannot tell how such a class spreads."""
        self._check_fitted()
        raw = np.asarray(self.var_) - self.epsilon_
        flat = raw < DEGENERATE_VARIANCE
        spike = flat.all(axis=1)
        gaussian = self.density == "gaussian" or (self.density == "auto" and len(self.classes_) == 2)
        if gaussian and "row" in self.feature_names_:  # a smoothed histogram is no spike: no bin is 0
            spike |= flat[:, self.feature_names_.index("row")]
        return [int(c) for c in self.classes_[spike]]

    def _check_fitted(self) -> None:
        if not hasattr(self, "classes_"):
            raise InputError("classifier is not fitted; call fit(images, labels) first")

    # -- evaluation ----------------------------------------------------------------------------
    def feature_groups(self, image) -> list[tuple[str, np.ndarray]]:
        """The model's features of an (H, W, 3) uint8 image
        (:func:`pcreg.classification.features.feature_groups`), to hand to :meth:`decision_function`
        when they are computed (and timed) apart; a :class:`~pcreg.frame.PreparedFrame`'s are made once
        and kept with it (every classifier of these features finds them there)."""
        return frame_features(image, self.features, weights=self.weights)

    def _sum_tables(self, image, tables: np.ndarray, groups=None) -> np.ndarray:
        return table_sum(image, tables, self.features, weights=self.weights, groups=groups)

    def _jll_planes(self, image: np.ndarray) -> list[np.ndarray]:
        self._check_fitted()
        image = check_image(image)
        return [self._sum_tables(image, self._tables64[i]) + self._log_prior[i] for i in range(len(self.classes_))]

    def joint_log_likelihood(self, image: np.ndarray) -> np.ndarray:
        """(H, W, n) float64: log p(c) + sum_f log p_cf(x_f) for each trained class (``p_cf`` the class's
        density of feature f: N(theta_cf, var_cf), or its smoothed histogram)."""
        return np.stack(self._jll_planes(image), axis=-1)

    def predict_log_proba(self, image: np.ndarray) -> np.ndarray:
        """(H, W, N) float64 log-posteriors over every label value 0..N-1 of the class table (ground,
        obstacle, unknown by default); a class the model was not trained on (unknown, by default) gets -inf."""
        jll = self._jll_planes(image)
        m = np.maximum.reduce(jll) if len(jll) > 1 else jll[0]
        total = np.zeros_like(m)
        for j in jll:
            total += np.exp(j - m)
        log_norm = m + np.log(total)
        out = np.full(m.shape + (self.class_table.n_values,), -np.inf, dtype=np.float64)
        for c, j in zip(self.classes_, jll):
            out[:, :, c] = j - log_norm
        return out

    def predict_proba(self, image: np.ndarray) -> np.ndarray:
        """(H, W, N) float64 posteriors over the table's label values (:meth:`predict_log_proba`)."""
        return np.exp(self.predict_log_proba(image))

    def decision_function(self, image: np.ndarray, *, groups=None) -> np.ndarray:
        """(H, W) float32 log-odds ``log p(c1 | x) - log p(c0 | x)`` of a two-class model (``classes_``
        (c0, c1), ground and obstacle by default): positive where ``predict`` says c1.

        Evaluated through the fitted 256-entry float32 tables (``D_f[v] = log N(v; c1) - log N(v; c0)``
        per feature, summed, plus the log prior ratio): about one table look-up per feature and pixel.
        groups : the image's :meth:`feature_groups`, when already computed (the same result).
        """
        self._check_fitted()
        if self._diff32 is None:
            raise InputError(f"decision_function needs a two-class model, this one has {len(self.classes_)} classes")
        bias = np.float32(self._log_prior[1] - self._log_prior[0])
        d = table_sum(image, self._diff32, self.features, weights=self.weights, groups=groups).astype(np.float32, copy=False)
        d += bias
        return d

    def predict(self, image: np.ndarray) -> np.ndarray:
        """(H, W) uint8 labels, each one of ``classes_`` (the most probable trained class)."""
        self._check_fitted()
        image = check_image(image)
        if self._diff32 is not None:
            d = self._sum_tables(image, self._diff32)
            out = np.greater(d, np.float32(self._log_prior[0] - self._log_prior[1])).view(np.uint8)
            if self.classes_[0] == 0 and self.classes_[1] == 1:
                return out
            return self.classes_[out]
        planes = self._score_planes(image, None)
        best, idx = planes[0].copy(), np.zeros(planes[0].shape, np.uint8)
        for k, p in enumerate(planes[1:], start=1):  # argmax over the classes, the first of equals winning
            better = p > best
            idx[better] = k
            np.maximum(best, p, out=best)
        return self.classes_[idx]

    def class_scores(self, image, *, groups=None) -> np.ndarray:
        """(H, W, K) float32, K = ``len(classes_)``: channel k is ``log p(c_k) + sum_f log N(x_f; theta_kf,
        var_kf)`` for class ``classes_[k]``, the joint log-likelihood, a log-posterior up to one constant
        per pixel (:meth:`log_posteriors` subtracts it). Differences of two channels are log posterior
        odds; with two classes, channel 1 minus channel 0 is :meth:`decision_function` up to float32
        rounding (that method sums one table of differences, this one a table per class).

        Evaluated through the fitted 256-entry float32 tables, one look-up per feature, pixel and class:
        time and memory grow linearly with K. groups : the image's :meth:`feature_groups`, when already
        computed (made once here otherwise, for every class)."""
        from ._score_kernels import class_sums

        self._check_fitted()
        width = check_image(image).shape[1]  # a PreparedFrame's rgb: its features stay kept with it
        if groups is None:
            groups = self.feature_groups(image)
        return class_sums(groups, self._tables32, np.asarray(self._log_prior, np.float32), width=width)

    def _score_planes(self, image, groups) -> list[np.ndarray]:
        self._check_fitted()
        if groups is None:
            groups = self.feature_groups(image)
        return [table_sum(image, self._tables32[i], self.features, weights=self.weights, groups=groups)
                + np.float32(self._log_prior[i]) for i in range(len(self.classes_))]

    def log_posteriors(self, image, *, groups=None) -> np.ndarray:
        """(H, W, K) float32 normalised log-posteriors ``log p(c_k | x)`` over the trained classes
        ``classes_`` (:meth:`class_scores` minus their log-sum-exp at each pixel); ``exp`` sums to 1 over
        the last axis."""
        import cv2

        planes = self._score_planes(image, groups)
        m = np.maximum.reduce(planes)
        total = np.zeros_like(m)
        for p in planes:
            total += cv2.exp(p - m)
        lse = m + np.log(total)
        out = np.empty(m.shape + (len(planes),), np.float32)
        for k, p in enumerate(planes):
            np.subtract(p, lse, out=out[:, :, k])
        return out

    def score_error(self, images, labels, *, exclude_unknown: bool = True) -> float:
        """Error rate in percent over all pixels of the given frames (pooled), unknown truth left out."""
        images, labels = _as_lists(images, labels, self.class_table)
        n = self.class_table.n_values
        conf = np.zeros((n, n), dtype=np.int64)
        for im, lab in zip(images, labels):
            conf += confusion_matrix(self.predict(im), lab, exclude_unknown=exclude_unknown, classes=self.class_table)
        return error_from_confusion(conf)

    def to_sklearn(self):
        """An equivalent fitted :class:`sklearn.naive_bayes.GaussianNB` (for cross-checks); classes are
        the label values, features the columns of :func:`pcreg.classification.features.feature_matrix`."""
        from sklearn.naive_bayes import GaussianNB

        self._check_fitted()
        nb = GaussianNB(var_smoothing=self.var_smoothing, priors=None if self.priors is None else list(self.priors))
        nb.classes_ = self.classes_.astype(np.int64)
        nb.class_count_ = self.class_count_.copy()
        nb.class_prior_ = self.class_prior_.copy()
        nb.theta_ = self.theta_.copy()
        nb.var_ = self.var_.copy()
        nb.epsilon_ = self.epsilon_
        nb.n_features_in_ = len(self.feature_names_)
        return nb


#: Names moved to :mod:`pcreg.classification.weight_search`, still read here with a DeprecationWarning until 0.4.
_MOVED = ("WeightSearch", "colour_counts", "thesis_weight_search")


def __getattr__(name: str):
    if name in _MOVED:
        import warnings

        from . import weight_search

        warnings.warn(f"pcreg.classification.bayes.{name} is deprecated; use pcreg.classification.weight_search.{name}",
                      DeprecationWarning, stacklevel=2)
        return getattr(weight_search, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
