"""A sequence walked with increment k: every pair (i, i + k) registered, fused and scored."""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ..classification.bayes import fit_classifier
from ..classification.fusion import FusionConfig, WeightChoice, choose_weight, label_prior
from ..errors import InputError
from ..validation import check_callable, check_frames, check_int, short_repr
from .pair import (METHODS, PairRegistration, PairResult, PipelineConfig, flow_field, log_odds, process_pair,
                   register_pair)
from .prior import class_prior, warped_prior_log_odds
from .temporal import TemporalFusion, temporal_update

__all__ = ["SequenceResult", "run_sequence", "pair_indices", "resolve_fusion_frames"]


def pair_indices(n: int, k: int) -> list[tuple[int, int]]:
    """Pairs (i, i + k) of a sequence of ``n`` frames."""
    return [(i, i + k) for i in range(max(0, n - k))]


def resolve_fusion_frames(n: int, *, fusion_frames: int | None, train: str) -> int:
    """How many frames at the start of a sequence choose the fusion weight (and are never scored).

    Default: the training frames for ``train="first:K"``, else 10% of the sequence, at least 2.
    """
    if fusion_frames is not None:
        return int(fusion_frames)
    if train.startswith("first:"):
        return int(train.split(":", 1)[1])
    return max(2, int(math.ceil(0.1 * n)))


@dataclass(frozen=True)
class SequenceResult:
    """One sequence at one increment with one backend.

    k : increment. backend : ICP backend. fusion_frames : frames 0..C-1 that chose the weight.
    weight : :class:`~pcreg.classification.fusion.WeightChoice` (``pairs == 0`` when fixed or not choosable).
    temporal_weight : the same for the recursive (temporal) fusion, chosen on the same frames.
    flow_weight : the same for ``augmented_flow``.
    pairs : scored :class:`PairResult` (moving frame >= C). means : {method: mean error % over pairs}.
    failures : [{"reference", "moving", "reason"}] of the scored pairs. notes : why pairs are missing.
    seconds : wall time.
    """

    k: int
    backend: str
    fusion_frames: int
    weight: WeightChoice
    pairs: tuple[PairResult, ...]
    means: dict
    failures: tuple[dict, ...]
    notes: tuple[str, ...]
    seconds: float
    temporal_weight: WeightChoice | None = None
    flow_weight: WeightChoice | None = None

    def to_dict(self) -> dict:
        return {"k": self.k, "backend": self.backend, "fusion_frames": self.fusion_frames,
                "weight": self.weight.to_dict(),
                "temporal_weight": None if self.temporal_weight is None else self.temporal_weight.to_dict(),
                "flow_weight": None if self.flow_weight is None else self.flow_weight.to_dict(), "means": dict(self.means),
                "failures": [dict(f) for f in self.failures], "notes": list(self.notes),
                "pairs": [p.to_dict() for p in self.pairs], "seconds": self.seconds}


def _means(pairs: Sequence[PairResult]) -> dict:
    out = {}
    for m in METHODS:
        vals = np.array([p.errors[m] for p in pairs], dtype=np.float64)
        out[m] = float(np.nanmean(vals)) if np.isfinite(vals).any() else float("nan")
    return out


def _choose_temporal_weight(calib: list, frames: Sequence, *, fusion: FusionConfig) -> WeightChoice:
    """The temporal filter's weight: run the chains through the calibration pairs (in order) with each
    candidate weight, pool the errors of every fused frame, keep the best (ties: the smaller weight)."""
    grid = tuple(float(g) for g in fusion.grid)
    if not calib:
        return choose_weight([], grid=grid)
    wrong = np.zeros(len(grid), dtype=np.int64)
    total = 0
    trusts = {(i, j): _pair_trust(frames, i, j, T) for i, j, T, _, _ in calib}
    if any(t is not None for t in trusts.values()):
        # a dense field's chain weighs its carried labels as the stream does its dense prior, trusted per
        # pixel: at full trust STREAM_WEIGHT * STREAM_TRUST.dense. A weight chosen on the first 10% of
        # a 20-frame clip (one or two pairs) froze 12 into the chain of CamVid 0006R0_b, where the scene
        # changes: 7.06% error against 6.58% for plain at k = 1, 6.56% with this weight.
        from .stream import STREAM_WEIGHT
        from .trust import STREAM_TRUST

        w = STREAM_WEIGHT * STREAM_TRUST.dense
        return WeightChoice(w, (w,), (float("nan"),), len(calib), 0)
    for gi, w in enumerate(grid):
        state: dict[int, np.ndarray] = {}
        for i, j, T, d, pi in calib:
            fused, state[j] = temporal_update(d, state.get(i, frames[i].labels), T, pi=pi, weight=w, fusion=fusion,
                                              trust=trusts.get((i, j)))
            state.pop(i, None)
            truth = frames[j].labels
            keep = truth < 2
            wrong[gi] += int(np.count_nonzero((fused[keep] > 0) != (truth[keep] == 1)))
            if gi == 0:
                total += int(keep.sum())
    if total == 0:
        return choose_weight([], grid=grid)
    errors = 100.0 * wrong / total
    best = int(np.argmin(errors))
    return WeightChoice(grid[best], grid, tuple(float(e) for e in errors), len(calib), total)


def _odd_sized(frames: Sequence) -> dict[int, str]:
    """{index: reason} of the frames whose size differs from the sequence's most common size."""
    from collections import Counter

    if not frames:
        return {}
    (h, w), _ = Counter(f.shape for f in frames).most_common(1)[0]
    return {i: f"frame {f.name} is {f.shape[1]}x{f.shape[0]} px, the sequence's frames are {w}x{h}"
            for i, f in enumerate(frames) if f.shape != (h, w)}


def _check_sequence_args(frames: Sequence, *, k, config, train, fusion_frames, on_pair,
                         icp_callback) -> tuple[int, int | None]:
    """``(k, fusion_frames)`` checked; :class:`~pcreg.errors.InputError` on bad input."""
    check_frames(frames, "frames")
    k = check_int(k, "k", lo=1)
    if any(f.labels is None for f in frames):
        raise InputError("every frame needs labels to be scored")
    if not isinstance(config, PipelineConfig):
        raise InputError(f"config must be a PipelineConfig, got {type(config).__name__}")
    if not isinstance(train, str):
        raise InputError(f"train must be 'reference' or 'first:K', got {short_repr(train)}")
    if fusion_frames is not None:
        fusion_frames = check_int(fusion_frames, "fusion_frames", lo=0)
    check_callable(on_pair, "on_pair")
    check_callable(icp_callback, "icp_callback")
    if train != "reference":
        if not train.startswith("first:") or not train.split(":", 1)[1].isdigit() or int(train.split(":", 1)[1]) < 1:
            raise InputError(f"train must be 'reference' or 'first:K' with K >= 1, got {train!r}")
    return k, fusion_frames


class _Classifiers:
    """The naive Bayes of each reference frame (the last one kept), or one shared model (``first:K``)."""

    def __init__(self, frames: Sequence, *, train: str, features: tuple[str, ...]) -> None:
        self._frames, self._features = frames, features
        self._shared = None
        self._cache: dict[int, object] = {}
        self.refused: dict[int, str] = {}
        if train.startswith("first:"):
            K = int(train.split(":", 1)[1])
            if K >= len(frames):
                raise InputError(f"train first:{K} leaves no test frame in a sequence of {len(frames)} frames")
            self._shared = fit_classifier(frames[:K], features=features)

    def __call__(self, i: int):
        """Frame ``i``'s model; None when its labels cannot train one (each frame's own model: all unknown, or one
        class only), its reason in :attr:`refused`: that frame's pairs fail, not the sequence."""
        if self._shared is not None:
            return self._shared
        if i not in self._cache:
            self._cache.clear()
            try:
                self._cache[i] = fit_classifier([self._frames[i]], features=self._features)
            except InputError as exc:
                self._cache[i] = None
                self.refused[i] = f"reference frame {self._frames[i].name} cannot train naive Bayes: {exc}"
        return self._cache[i]


class _Registrations:
    """Each pair's :func:`register_pair`, computed once and kept until it is taken."""

    def __init__(self, frames: Sequence, config: PipelineConfig) -> None:
        self._frames, self._config = frames, config
        self._cache: dict[tuple[int, int], PairRegistration] = {}

    def __call__(self, i: int, j: int, callback=None) -> PairRegistration:
        if (i, j) not in self._cache:
            self._cache[(i, j)] = register_pair(self._frames[i].image, self._frames[j].image, config=self._config,
                                                callback=callback)
        return self._cache[(i, j)]

    def take(self, i: int, j: int, callback=None) -> PairRegistration:
        """The pair's registration, no longer kept."""
        reg = self(i, j, callback)
        self._cache.pop((i, j), None)
        return reg

    def keep_increment(self, k: int) -> None:
        """Forget every pair that is not ``k`` apart."""
        self._cache = {key: v for key, v in self._cache.items() if key[1] - key[0] == k}


@dataclass(frozen=True)
class _Weights:
    """The fusion weights of a sequence: one-step, temporal and flow, with the notes on their choice."""

    one_step: WeightChoice
    temporal: WeightChoice
    flow: WeightChoice
    notes: tuple[str, ...] = ()


def _fixed_choice(fusion: FusionConfig) -> WeightChoice:
    """The choice of a fixed weight (or of 1 where none could be chosen): no pairs, NaN errors."""
    fixed = fusion.weight
    return WeightChoice(float(fixed if fixed is not None else 1.0), fusion.grid,
                        tuple(float("nan") for _ in fusion.grid), 0, 0)


def _pair_trust(frames: Sequence, i: int, j: int, motion) -> np.ndarray | None:
    """The trust in labels carried from frame ``i`` to frame ``j`` by a dense field (as
    :func:`pcreg.pipeline.pair.process_pair` weighs them), None for a global transform."""
    from ..registration.motion import Motion
    from .trust import residual_trust

    if motion is None:
        return None
    m = Motion.of(motion)
    return None if m.field is None else residual_trust(frames[i].image, frames[j].image, m.field)


def _prior_samples(calib: list, frames: Sequence, fusion: FusionConfig, motion: Callable, *,
                   weighed: bool = False) -> list:
    """``(d, prior log-odds, truth)`` of every calibration pair whose ``motion(i, j, T)`` is not None;
    ``weighed``: a dense field's prior times its per-pixel factors (the field's confidence span and the
    trust of :func:`_pair_trust`), so that the weight is chosen for the fusion as it is made."""
    from ..registration.motion import Motion
    from .prior import pixel_weight

    samples = []
    for i, j, T, d, pi in calib:
        m = motion(i, j, T)
        if m is None:
            continue
        l_prior = warped_prior_log_odds(label_prior(frames[i].labels, pi=pi, fusion=fusion), m,
                                        shape=frames[j].shape, pi=pi)
        mo = Motion.of(m)
        if weighed and mo.field is not None:
            trust = _pair_trust(frames, i, j, mo)
            assert trust is not None  # a field's
            l_prior = (l_prior * pixel_weight(1.0, mo.confidence) * trust).astype(np.float32)
        samples.append((d, l_prior, frames[j].labels))
    return samples


def _choose_weights(frames: Sequence, *, k: int, C: int, fusion: FusionConfig, classifier: _Classifiers,
                    registration: _Registrations, odd: dict[int, str]) -> _Weights:
    """The fusion weights (one-step, temporal and flow), chosen on the pairs among the first C frames
    at increment min(k, C - 1); a fixed ``fusion.weight`` is used as it is."""
    if fusion.weight is not None:
        fixed = _fixed_choice(fusion)
        return _Weights(fixed, fixed, fixed)
    kc = min(k, C - 1)
    calib = []  # (i, j, T, d_j, pi) of the registered pairs among the first C frames, in order
    if kc >= 1:
        for i, j in pair_indices(C, kc):
            if i in odd or j in odd:
                continue
            clf = classifier(i)
            if clf is not None:
                calib.append((i, j, registration(i, j).motion, log_odds(clf, frames[j].image), class_prior(clf)))
    choice = choose_weight(_prior_samples(calib, frames, fusion, lambda i, j, T: T, weighed=True), grid=fusion.grid)
    flow_samples = _prior_samples(calib, frames, fusion, lambda i, j, T: flow_field(frames[i].image, frames[j].image))
    flow_choice = choose_weight(flow_samples, grid=fusion.grid)
    temporal_choice = _choose_temporal_weight(calib, frames, fusion=fusion)
    notes: tuple[str, ...] = ()
    if choice.pairs == 0:
        notes = (f"no registered pair among the first {C} frames to choose the fusion weight: "
                 f"w = {choice.weight} used",)
    elif kc != k:
        notes = (f"fusion weight chosen at increment {kc} (the first {C} frames hold no pair {k} apart)",)
    errors = np.asarray(temporal_choice.errors, dtype=np.float64)
    if temporal_choice.pairs and np.isfinite(errors).all() and np.ptp(errors) == 0:
        notes += (f"temporal fusion weight not determined: every weight scored the same on the first {C} frames "
                  f"({errors[0]:.2f}% error; no label the chain carried reached a frame there), w = "
                  f"{temporal_choice.weight:g} used" + (": augmented_temporal is naive Bayes alone"
                                                         if temporal_choice.weight == 0 else ""),)
    registration.keep_increment(k)
    return _Weights(choice, temporal_choice, flow_choice, notes)


@dataclass(frozen=True)
class _Walk:
    """The scored pairs of a sequence and the failures among them."""

    scored: tuple[PairResult, ...]
    failures: tuple[dict, ...]


def _walk_pairs(frames: Sequence, *, k: int, C: int, config: PipelineConfig, weights: _Weights,
                classifier: _Classifiers, registration: _Registrations, odd: dict[int, str],
                on_pair: Callable | None, icp_callback: Callable | None) -> _Walk:
    """Every pair (i, i + k) in order: the temporal chains need all of them, the scores those with j >= C."""
    chains: deque = deque()
    scored: list[PairResult] = []
    failures: list[dict] = []
    for i, j in pair_indices(len(frames), k):
        chain = chains.popleft() if i >= k else None
        clf = None if i in odd or j in odd else classifier(i)
        if clf is None:
            if j >= C:
                failures.append({"reference": i, "moving": j,
                                 "reason": odd[i] if i in odd else odd[j] if j in odd else classifier.refused[i]})
            chains.append(None)  # the chain restarts after the odd frame
            continue
        if chain is None:
            chain = TemporalFusion(frames[i].labels, weight=weights.temporal.weight, fusion=config.fusion)
        score = j >= C
        reg = registration.take(i, j, icp_callback if score else None)
        if score:
            done = process_pair(frames[i], frames[j], clf, weight=weights.one_step.weight, config=config,
                                registration=reg, temporal=chain, indices=(i, j), keep_arrays=on_pair is not None,
                                flow_weight=weights.flow.weight)
            scored.append(done.result)
            if not done.result.registered:
                failures.append({"reference": i, "moving": j, "reason": done.result.reason})
            if on_pair is not None:
                on_pair(done.result, (frames[i], frames[j]), done.arrays)
        else:
            chain.step(log_odds(clf, frames[j].image), reg.motion, pi=class_prior(clf))
        chains.append(chain)
    return _Walk(tuple(scored), tuple(failures))


def run_sequence(frames: Sequence, *, k: int, config: PipelineConfig = PipelineConfig(), train: str = "reference",
                 fusion_frames: int | None = None, on_pair: Callable | None = None,
                 icp_callback: Callable | None = None) -> SequenceResult:
    """Walk a labelled sequence with increment ``k``: every method on the pairs (i, i + k).

    frames : labelled :class:`~pcreg.datasets.Frame` of one size, in order.
    train : ``"reference"`` (naive Bayes trained on each pair's reference frame, as the thesis) or
        ``"first:K"`` (trained once on frames 0..K-1).
    fusion_frames : frames 0..C-1 choose the fusion weight (pairs among them, at increment
        min(k, C - 1), scored against their moving frame's labels); only pairs whose moving frame is
        >= C are scored (default: :func:`resolve_fusion_frames`). A fixed ``config.fusion.weight``
        skips the choice.
    on_pair : called as ``on_pair(pair_result, frames, arrays)`` for each scored pair, with the arrays
        of :func:`process_pair` (for recordings); None keeps them off the hot path.
    icp_callback : passed to :func:`pcreg.register` (per-iteration hook) for the scored pairs.

    Bad input (``k < 1``, unlabelled frames, a bad ``train``) raises :class:`~pcreg.errors.InputError`;
    a sequence too short for ``k`` gives no pairs and a note.
    """
    t_start = time.perf_counter()
    k, fusion_frames = _check_sequence_args(frames, k=k, config=config, train=train, fusion_frames=fusion_frames,
                                            on_pair=on_pair, icp_callback=icp_callback)
    n = len(frames)
    C = resolve_fusion_frames(n, fusion_frames=fusion_frames, train=train)
    if C < 0:
        raise InputError("fusion_frames must be >= 0")
    if fusion_frames is not None and C > n:
        raise InputError(f"fusion_frames {C} is more than the sequence's {n} frames")
    if n < 2 or k >= n:
        note = (f"{n} frame(s): no pairs" if n < 2
                else f"increment k={k} is not shorter than the sequence ({n} frames): no pairs")
        empty = _fixed_choice(config.fusion)
        return SequenceResult(k, config.backend, C, empty, (), _means([]), (), (note,),
                              time.perf_counter() - t_start, temporal_weight=empty)

    classifier = _Classifiers(frames, train=train, features=config.features)
    registration = _Registrations(frames, config)
    odd = _odd_sized(frames)  # a frame of another size fails its own pairs only, with the reason
    weights = _choose_weights(frames, k=k, C=C, fusion=config.fusion, classifier=classifier,
                              registration=registration, odd=odd)
    walk = _walk_pairs(frames, k=k, C=C, config=config, weights=weights, classifier=classifier,
                       registration=registration, odd=odd, on_pair=on_pair, icp_callback=icp_callback)
    notes = weights.notes
    if not walk.scored and walk.failures:  # the pairs were there: each failed, the first's reason says why
        first = walk.failures[0]
        notes += (f"no pair scored: {len(walk.failures)} pair(s) failed, the first ({first['reference']}, "
                  f"{first['moving']}): {first['reason']}",)
    elif not walk.scored:
        notes += (f"no pair with its moving frame after the {C} fusion frames",)
    return SequenceResult(k, config.backend, C, weights.one_step, walk.scored, _means(walk.scored), walk.failures,
                          notes, time.perf_counter() - t_start, temporal_weight=weights.temporal,
                          flow_weight=weights.flow)
