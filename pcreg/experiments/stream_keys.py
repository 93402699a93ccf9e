"""``pcreg evaluate stream --keys SPEC``: key frames anywhere in a clip, every other frame labelled from the
key frames around it, forwards and backwards (:func:`pcreg.pipeline.keyframes.label_clip`).

SPEC (:func:`key_indices`): ``first``; ``first,last``; ``every:N`` (frames 0, N, 2N, ...); ``spaced:N`` (N
frames evenly spaced from frame 0: what ``--key-every`` gives with N key frames); ``suggest:N``
(frame 0, then the N - 1 frames :func:`pcreg.pipeline.keyframes.suggest` picks from the predicted error
of a run from frame 0 alone: no label of any other frame is used to choose); or frame indices
(``0,12,29``). Each frame that is not a key frame is scored. ``plain`` and the baselines fit naive Bayes on
all the key frames; ``pcreg`` fits each stretch's on its own key frames, as ``pcreg run`` does
(:data:`~pcreg.pipeline.keyframes.KEY_FITS`).

The methods (:data:`KEY_METHODS`): ``plain`` (naive Bayes alone); ``unregistered`` (the key frames'
labels unmoved); ``pcreg`` (:func:`~pcreg.pipeline.keyframes.label_clip`), ``pcreg_half`` and ``pcreg_flow``
(the same at half size, and on DIS's flow at half size: :data:`pcreg.experiments.stream.PCREG_METHODS`); ``flow_key`` and
``flowultrafast_key`` (each key frame's prior warped by DIS, medium or ultrafast preset, from that key
frame). The baselines weight the two key frames around a frame by its distance in frames to each
(the nearer key frame more, linearly; one key frame alone on a one-sided stretch) and fuse at the
stream's weight 2.
"""

from __future__ import annotations

import re
import time

import numpy as np

__all__ = ["KEY_METHODS", "key_indices", "check_key_spec", "run_clip_keys"]

#: A frame index or N as SPEC writes it: ASCII digits, a sign allowed (refused later as out of range); not
#: ``1_0`` or other digits Python's ``int`` reads.
_WHOLE = re.compile(r"[+-]?[0-9]+")


def _whole(digits: str) -> int:
    """A number :data:`_WHOLE` matched; one of more than 18 digits, leading zeros aside, beyond any clip (and, past
    4300, beyond what ``int()`` reads from a string), as 10**18 with its sign, for the range checks to refuse."""
    body = digits.lstrip("+-").lstrip("0") or "0"
    sign = -1 if digits.startswith("-") else 1
    return sign * (int(body) if len(body) <= 18 else 10**18)


def _shown(spec: str) -> str:
    """``spec`` as a message shows it: a run of more than 20 digits cut to its ends and its length (a line cut
    at its end would lose the reason after it)."""
    return re.sub(r"[0-9]{21,}", lambda m: f"{m[0][:3]}...{m[0][-3:]} ({len(m[0])} digits)", spec)

#: Methods of the key-frame protocol, in table order.
KEY_METHODS: tuple[str, ...] = ("plain", "unregistered", "pcreg", "pcreg_half", "pcreg_flow", "flow_key",
                                 "flowultrafast_key")


def key_indices(spec: str, n: int, frames=None, *, backend: str = "reference", classes=None) -> list[int]:
    """The key frames of a clip of ``n`` frames by ``spec`` (the module's docstring). ``suggest:N`` runs
    pcreg from frame 0 (``frames`` with images and frame 0's labels, ids of the class table ``classes``:
    :func:`pcreg.classes.class_table`'s spec, None for ``lagr``) and picks from its predicted errors.
    Key frames that are every frame of the clip leave nothing to score: an :class:`InputError`."""
    from ..errors import InputError

    keys = _key_indices(spec, n, frames, backend=backend, classes=classes)
    if len(set(keys)) >= n:
        raise InputError(f"--keys {_shown(spec)}: every one of the clip's {n} frames is a key frame: nothing is scored")
    return keys


def check_key_spec(spec: str, n: int) -> None:
    """Refuse ``spec`` on a clip of ``n`` frames as :func:`key_indices` would, without running anything
    (``suggest:N`` has its N checked, its frames chosen only when the clip runs)."""
    from ..errors import InputError

    kind, _, arg = _normal(spec).partition(":")
    if kind != "suggest":
        key_indices(spec, n)
        return
    if not _WHOLE.fullmatch(arg):
        raise InputError(f"--keys {_shown(spec)}: suggest:N takes a whole number")
    k = _whole(arg)
    if not 1 <= k <= n:
        raise InputError(f"--keys {_shown(spec)}: suggest:N needs 1 <= N <= {n} (the clip's frames)")
    if k >= n:
        raise InputError(f"--keys {_shown(spec)}: every one of the clip's {n} frames is a key frame: nothing is scored")


def _normal(spec: str) -> str:
    """``spec`` without the spaces around its commas and colons (``first, last``, ``spaced: 3``)."""
    return re.sub(r"\s*([,:])\s*", r"\1", spec.strip())


def _key_indices(spec: str, n: int, frames=None, *, backend: str = "reference", classes=None) -> list[int]:
    from ..errors import InputError
    from ..pipeline.keyframes import label_clip, suggest

    s = _normal(spec)
    if s == "first":
        return [0]
    if s in ("first,last", "last,first"):
        return sorted({0, n - 1})
    kind, _, arg = s.partition(":")
    if kind in ("every", "suggest", "spaced"):
        if not _WHOLE.fullmatch(arg):
            raise InputError(f"--keys {_shown(spec)}: {kind}:N takes a whole number")
        k = _whole(arg)
        if kind == "every":
            if k < 1:
                raise InputError(f"--keys {_shown(spec)}: every:N needs N >= 1")
            return list(range(0, n, k))
        if kind == "spaced":
            if not 1 <= k <= n:
                raise InputError(f"--keys {_shown(spec)}: spaced:N needs 1 <= N <= {n} (the clip's frames)")
            return sorted({int(round(i * n / k)) for i in range(k)})
        if not 1 <= k <= n:
            raise InputError(f"--keys {_shown(spec)}: suggest:N needs 1 <= N <= {n} (the clip's frames)")
        if k == 1:
            return [0]
        if frames is None:
            raise InputError("--keys suggest:N needs the clip's frames")
        from .stream_methods import counted

        # a pass of pcreg over the clip: its frames are steps of the unit's work on the command's bar
        first = label_clip(lambda t: frames[t].image, n, {0: frames[0].labels}, backend=backend, classes=classes,
                           on_frame=counted([0]))
        predicted = {f.index: f.predicted_error for f in first if f.index != 0}
        return sorted([0] + suggest(predicted, [0], k - 1, n))
    values = s.split(",")
    if not all(_WHOLE.fullmatch(v) for v in values):
        raise InputError(f"--keys {_shown(spec)}: not first, first,last, every:N, spaced:N, suggest:N or frame indices")
    idx = sorted({_whole(v) for v in values})
    if not idx or idx[0] < 0 or idx[-1] >= n:
        raise InputError(f"--keys {_shown(spec)}: frame indices must lie in 0..{n - 1}")
    return idx


def _baseline_prior(fields: dict, priors: dict, t: int, a: int | None, b: int | None) -> np.ndarray:
    """The key frames' priors around frame ``t``, each carried by its field (None: unmoved), weighted by
    the frame's distance to each: log-odds (H, W) float32."""
    from ..classification.fusion import prior_log_odds
    from ..pipeline.prior import warped_prior_log_odds

    if a is not None and b is not None:
        around = [(a, (b - t) / (b - a)), (b, (t - a) / (b - a))]
    else:
        around = [(k, 1.0) for k in (a, b) if k is not None]
    parts = []
    for k, share in around:
        q, pi = priors[k]
        fld = fields.get(k)
        l_prior = prior_log_odds(q, pi=pi) if fld is None else warped_prior_log_odds(q, fld, shape=q.shape, pi=pi)
        parts.append(share * l_prior)
    return np.sum(parts, axis=0).astype(np.float32)


class _AroundKeys:
    """A baseline between key frames, as a labeller of the frames of one stretch in order
    (:func:`pcreg.pipeline.engine.propagate`): naive Bayes alone (``plain``), or fused with the key frames'
    priors around each frame, unmoved (``unregistered``) or each carried by DIS from its key frame
    (:func:`_baseline_prior`)."""

    def __init__(self, method: str, classifier, frames, stretch, priors: dict) -> None:
        from ..pipeline.estimators import FlowEstimator
        from .stream_methods import PRESET_OF

        self.method, self.classifier, self.frames, self.stretch, self.priors = method, classifier, frames, stretch, priors
        self.flow = FlowEstimator(PRESET_OF[method.split("_")[0]]) if method not in ("plain", "unregistered") else None
        self.t = stretch.start

    def step(self, image: np.ndarray) -> np.ndarray:
        from ..pipeline.pair import log_odds
        from ..pipeline.stream import STREAM_WEIGHT

        t, s = self.t, self.stretch
        self.t += 1
        d = log_odds(self.classifier, image)
        if self.method == "plain":
            return (d > 0).astype(np.uint8)
        fields = {} if self.flow is None else {k: self.flow.estimate(self.frames[k].image, image).result.field  # type: ignore[union-attr]
                                               for k in s.keys}
        return ((d + STREAM_WEIGHT * _baseline_prior(fields, self.priors, t, s.first, s.last)) > 0).astype(np.uint8)


def run_clip_keys(frames, keys: list[int], *, methods=KEY_METHODS, backend: str = "reference", on_frame=None) -> dict:
    """Every method on one clip with these key frames; the same result layout as
    :func:`pcreg.experiments.stream.run_clip` (``key`` of a row: the nearest key frame before it, or
    after it before the first). The pcreg methods label the clip with
    :func:`~pcreg.pipeline.keyframes.label_clip`; each baseline is a pass along each stretch
    (:func:`~pcreg.pipeline.engine.propagate`). ``on_frame(index, frame, predictions, key_frame)`` is called
    for every scored frame, in the clip's order (a recording hook)."""
    from ..classification.bayes import fit_classifier
    from ..classification.fusion import label_prior
    from ..classification.metrics import error_rate
    from ..pipeline.engine import propagate, stretches
    from ..pipeline.keyframes import label_clip
    from ..pipeline.prior import class_prior
    from .._progress import unit_work
    from .stream_methods import CONFIDENCE_LEVELS, PCREG_METHODS, Timed, calibration_counts, counted, kernels_ready

    n = len(frames)
    unit_work((n - len(set(keys))) * len(methods))
    clf = fit_classifier([frames[k] for k in keys])
    pi = class_prior(clf)
    priors = {k: (label_prior(frames[k].labels, pi=pi), pi) for k in keys}
    seconds = dict.fromkeys(methods, 0.0)
    ours: dict = {}  # each pcreg method's frames, by index
    for m in (m for m in PCREG_METHODS if m in methods):
        kernels_ready()  # compiled before the clock starts, as a Timed step's
        t0 = time.perf_counter()
        ours[m] = {f.index: f for f in label_clip(lambda t: frames[t].image, n, {k: frames[k].labels for k in keys},
                                                  backend=backend, on_frame=counted(keys), **PCREG_METHODS[m])}
        seconds[m] = time.perf_counter() - t0
    counts = np.zeros((2, CONFIDENCE_LEVELS), np.int64)
    rows = []
    for s in stretches(keys, n):
        errors: dict[int, dict] = {t: {} for t in s.frames}
        preds: dict[int, dict] = {t: {} for t in s.frames}
        for m in methods:
            if m in ours:
                for t in s.frames:
                    errors[t][m] = error_rate(ours[m][t].labels, frames[t].labels)
                    if on_frame is not None:
                        preds[t][m] = ours[m][t].labels
                continue
            timed = Timed(_AroundKeys(m, clf, frames, s, priors))
            for t, _, labels in propagate(timed, ((t, frames[t].image) for t in s.frames)):
                errors[t][m] = error_rate(labels, frames[t].labels)
                if on_frame is not None:
                    preds[t][m] = labels
            seconds[m] += timed.seconds
        for t in s.frames:
            if "pcreg" in ours:
                conf = ours["pcreg"][t].confidence
                assert conf is not None  # a frame that is not a key frame has one
                counts += calibration_counts(conf, ours["pcreg"][t].labels, frames[t].labels)
            key = s.first if s.first is not None else s.last
            assert key is not None  # a stretch has a key frame on one side at least
            rows.append({"index": t, "name": frames[t].name, "key": key, "since_key": abs(t - key),
                         "errors": {m: errors[t][m] for m in methods}})
        if on_frame is not None:  # the stretch's frames in the clip's order (one before the first key runs backwards)
            key = s.first if s.first is not None else s.last
            for t in sorted(s.frames):
                on_frame(t, frames[t], preds.pop(t), frames[key])
    rows.sort(key=lambda r: r["index"])
    means = {m: float(np.nanmean([r["errors"][m] for r in rows])) if rows else float("nan") for m in methods}
    return {"frames": rows, "means": means, "key_frames": sorted(keys), "calibration": counts.tolist(),
            "ms_per_frame": {m: 1000.0 * s / max(1, len(rows)) for m, s in seconds.items()}}
