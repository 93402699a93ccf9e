"""A naive Bayes that learns from the frames it labels with confidence, never outweighing the key frame.

Naive Bayes (:class:`~pcreg.classification.bayes.NaiveBayesPixelClassifier`) is fitted from per-class
feature histograms, so learning from the stream is adding histograms. After each step, the pixels
whose carried priors are sure (their trusted log-odds beyond ``sure``) and agree with the fused label
are counted with that label, one pixel in ``stride`` along each axis; the stream's histogram decays
by ``decay`` a frame before the new counts are added; and the classifier is refitted on the key
frame's histogram plus the stream's, scaled down, when it holds more, to ``share`` of the key frame's
pixels. So the hand labels always weigh at least twice what the whole stream does (``share`` 0.5), and
no single frame can outweigh them. The classifier follows a change of light or a surface the key frame
never showed, and the unknown pixels (sky, void) carry no prior and are never learned.

Measured on the eight shared CamVid clips, each clip's settings chosen on the other seven
(docs/results.md, "Trust"): learning adds about half a point of reduction against plain; the result
hardly moves over share 0.25-1, decay 0-0.9 and sure 2-8.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import InputError

__all__ = ["Learning", "STREAM_LEARNING", "Learner", "learns"]


def learns(classifier) -> bool:
    """Whether a stream can teach ``classifier``: a fitted pcreg naive Bayes (it keeps its histograms)."""
    from ..classification.bayes import NaiveBayesPixelClassifier

    return isinstance(classifier, NaiveBayesPixelClassifier) and hasattr(classifier, "counts_")


@dataclass(frozen=True)
class Learning:
    """How the classifier learns from the stream (see the module's docstring)."""

    share: float = 0.5
    decay: float = 0.9
    sure: float = 4.0
    stride: int = 3

    def __post_init__(self) -> None:
        from ..validation import check_float, check_int

        check_float(self.share, "learning share", lo=0, hi=1)
        check_float(self.decay, "learning decay", lo=0, hi=1)
        check_float(self.sure, "learning sure", lo=0, hi=1e6)
        check_int(self.stride, "learning stride", lo=1, hi=64)


#: The stream's learning (docs/results.md, "Trust").
STREAM_LEARNING = Learning()


class Learner:
    """The key frame's classifier and what the stream has taught it.

    :meth:`update` takes a labelled frame's sure pixels and returns at once; they are counted, and the
    classifier refitted, when the classifier is next wanted (:attr:`classifier`, on the helper thread in
    a stream's next step, beside its registration) or the histogram read (:attr:`stream`): the same
    numbers as counting them at once, off the step's own path."""

    def __init__(self, classifier, rule: Learning) -> None:
        from ..classification.bayes import NaiveBayesPixelClassifier

        if not isinstance(classifier, NaiveBayesPixelClassifier) or not hasattr(classifier, "counts_"):
            raise InputError("learning from the stream needs a fitted pcreg NaiveBayesPixelClassifier")
        self.key_classifier, self.rule = classifier, rule
        self._key = np.asarray(classifier.counts_, dtype=np.float64)
        self._key_pixels = float(self._key[:, 0].sum())
        self._stream = np.zeros_like(self._key)
        self._classifier = classifier
        self._pending: tuple[np.ndarray, np.ndarray] | None = None

    @property
    def classifier(self):
        """The classifier as learned so far (what :meth:`update` gave it counted first)."""
        self._learn_pending()
        return self._classifier

    @property
    def stream(self) -> np.ndarray:
        """(N, F, 256) float64 (N the class table's values, 3 by default): the stream's decayed histogram so far (what :meth:`update` gave it counted
        first)."""
        self._learn_pending()
        return self._stream

    def stream_later(self) -> Callable[[], np.ndarray]:
        """What :attr:`stream` is now, to be computed when called, on any thread, without changing the
        learner: its frames not counted yet stay for the helper thread to count (a saved histogram
        written beside the next step, as ``pcreg run`` writes it)."""
        stream, pending, decay = self._stream, self._pending, self.rule.decay  # replaced, never written into
        if pending is None:
            return stream.copy
        features, weights = self.key_classifier.features, self.key_classifier.weights
        table = self.key_classifier.class_table

        def later() -> np.ndarray:
            from ..classification.bayes import class_histograms

            return decay * stream + class_histograms(pending[0], pending[1], features, weights=weights, classes=table)

        return later

    def restore(self, stream: np.ndarray | None) -> None:
        """Continue from a saved :attr:`stream` histogram (None: nothing learned yet); one refused leaves the
        learner as it was."""
        if stream is None:
            s = np.zeros_like(self._key)
        else:
            given = np.asarray(stream)
            if given.dtype.kind not in "biuf":  # a string or complex histogram: not a number each, refused
                raise InputError(f"a learned histogram must be finite, >= 0 and of shape {self._key.shape}, got "
                                 f"{given.dtype}")
            s = given.astype(np.float64)
            if s.shape != self._key.shape or not np.all(np.isfinite(s)) or s.min(initial=0.0) < 0:
                raise InputError(f"a learned histogram must be finite, >= 0 and of shape {self._key.shape}")
        classifier = self._refit(s)  # a histogram the classifier refuses (unknown pixels counted) refused here
        self._stream, self._pending, self._classifier = s, None, classifier

    def snapshot(self) -> tuple:
        """The learner as it is now, for :meth:`rewind` (its histograms and classifier are replaced, never written
        into)."""
        return self._stream, self._pending, self._classifier

    def rewind(self, snapshot: tuple) -> None:
        """Go back to a :meth:`snapshot` (a stream's step that raised: what it taught is forgotten)."""
        self._stream, self._pending, self._classifier = snapshot

    def update(self, image, fused: np.ndarray, prior_term: np.ndarray) -> None:
        """Learn from one labelled frame (an (H, W, 3) uint8 image or a
        :class:`~pcreg.frame.PreparedFrame`): ``fused`` (H, W) log-odds, ``prior_term`` (H, W) the trusted
        priors' part of them (with more than two classes (H, W, K) class scores and their priors' part). Its sure pixels are kept, one in ``stride`` along each axis, and counted
        when the classifier is next wanted."""
        from ..frame import as_rgb_uint8

        self._learn_pending()
        s = self.rule.stride
        F, P = fused[::s, ::s], prior_term[::s, ::s]
        if F.ndim == 3:  # K classes: fused class scores (:func:`~pcreg.pipeline.multiclass.sure_labels`)
            from .multiclass import sure_labels

            clf = self.key_classifier
            labels = sure_labels(F, P, clf.classes_, clf.class_table.unknown, sure=self.rule.sure)
        else:
            sure = (np.abs(P) > self.rule.sure) & ((P > 0) == (F > 0))
            labels = np.where(sure, (F > 0).astype(np.uint8), np.uint8(2)).astype(np.uint8)
        # a copy of its own (a one-in-one sample is the frame itself): the caller may write the next frame into it
        self._pending = (np.array(as_rgb_uint8(image, name="frame")[::s, ::s], order="C"), labels)

    def _learn_pending(self) -> None:
        if self._pending is None:
            return
        self._stream, self._pending = self.stream_later()(), None
        self._classifier = self._refit(self._stream)

    def _refit(self, stream: np.ndarray):
        """The key frame's classifier refitted with ``stream`` (what was learned) added at the rule's share."""
        n = float(stream[:, 0].sum())
        if n == 0 or self.rule.share == 0:
            return self.key_classifier
        scale = min(1.0, self.rule.share * self._key_pixels / n)
        return self.key_classifier.unfitted().fit_histograms(np.rint(self._key + scale * stream).astype(np.int64))
