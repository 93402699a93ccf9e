"""Whether the images pin :func:`~pcreg.registration.api.register`'s result down: the result refined again from
two starts a few pixels off.

A right result is where the refinement comes back to: its edges hold it from every side. A result on a blurred,
featureless or repetitive picture can sit in a valley of alignments as good as one another (a motion-blurred
clock's outline fits many scales and turns), or on a ledge the refinement left too early, beside a clearly better
alignment. Edge ICP's own evidence (the share of edge points lined up, :mod:`.plausibility`) cannot tell either
from the result alone: on the shared photographs' views, wrong results lined up 3.1-4.3 times what chance gives,
right ones 3.4 times and more.

So the result is refined again (:meth:`~pcreg.registration.search.GlobalSearch.refine`, from pyramid level 1) from
two starts that move the moving image's corners by :data:`NUDGE_PX`: turned about the image's centre, and scaled
about it (a shift where the model has no turn or no scale). Each alternative is then measured as the result was:

- one that lines up more edge points by :data:`~.plausibility.SIGNIFICANCE` standard deviations of the result's
  count (binomial over its overlapping points) is a better alignment the result fell short of: it is taken, and
  checked the same way from its own starts, however near the result it lies (one within
  :data:`~.plausibility.SHIFT_PX` was left: the blurred clock in perspective came back 4.2 px off a grid of the
  view beside an alignment of 90% of its edge points against 84%, which is 0.7 px off);
- one that moves some moving edge point landing on the reference (at level 1, as
  :func:`~.plausibility.model_fit` reads them) by more than :data:`~.plausibility.SHIFT_PX` from the result and
  lines up as many (not fewer by that margin) means the images do not determine the motion: the result is
  refused.

Refining again from the result itself ends where it is, so the check reads only how the result's neighbourhood
behaves. The rules are stated, not fitted: twice the distance within which a result counts as right, and the
significance that the model check and the chance test use. Measured on docs/algorithms.md's views and held-out
photographs ("Does the refinement come back?").
"""

from __future__ import annotations

import numpy as np

from ..errors import RegistrationError
from .global_search import gray_level
from .plausibility import SHIFT_PX, SIGNIFICANCE, largest_move
from .result import Settling
from .search import Candidate, Hypothesis
from .transforms import about_point, degeneracy, image_center, rigid2d

__all__ = ["NUDGE_PX", "Settling", "nudges", "settle"]

NUDGE_PX = 2 * SHIFT_PX
"""How far the check's starts move the moving image's corners from the result (px at full size): twice the
distance within which a result counts right, so that a start is off by more than a right result may be, and
within the first pass's gate at pyramid level 1 (10 px: the 2.5 px correspondence distance, doubled at level 1
and doubled again for a start's first pass)."""

TOP_LEVEL = 1
"""The pyramid level the alternatives are refined from: the starts lie a few px off, within level 1's first
gate; from the coarsest level, lines of text pulled right results of a page 17-255 px away."""


def nudges(model: str, shape: tuple[int, ...]) -> list[np.ndarray]:
    """The two 3x3 moves of the moving image (of ``shape``) that the check starts from, each moving its farthest
    corner by :data:`NUDGE_PX`: a turn about its centre and a scale about it; a shift along the diagonal in place
    of the scale for ``rigid``, two shifts (along x, then y) for ``translation``."""
    centre = image_center(shape)
    radius = max(float(np.hypot(*centre)), 1.0)
    if model == "translation":
        return [rigid2d(tx=NUDGE_PX), rigid2d(ty=NUDGE_PX)]
    turn = about_point(rigid2d(np.degrees(NUDGE_PX / radius)), centre)  # a turn of a radians moves a corner by about radius * a
    if model == "rigid":
        return [turn, rigid2d(tx=NUDGE_PX / np.sqrt(2.0), ty=NUDGE_PX / np.sqrt(2.0))]
    return [turn, about_point(rigid2d(scale=1.0 + NUDGE_PX / radius), centre)]


def settle(best: Candidate, moving, search, test, shape: tuple[int, ...]
           ) -> tuple[Candidate, Settling | None, RegistrationError | None]:
    """``(result, settling, refusal)``: ``best`` (a :class:`~pcreg.registration.search.Candidate` of ``search``'s
    refinement, measured by ``test``, a :class:`~.plausibility.Plausibility`) or the better alternative that
    replaces it, what the check found (None where no alternative could be refined or measured), and the refusal
    when an alternative as good lies elsewhere (None otherwise). A better alternative taken is checked as the
    result was: from its own nudged starts, any alternative as good or better elsewhere refuses it (a result that
    keeps improving has not settled). See the module's description."""
    check = _Around(moving, search, test, shape)
    pool = check.alternatives(best)
    if not pool:
        return best, None, None
    better = [c for c in pool if c.inlier_ratio - best.inlier_ratio > check.margin(best)]
    chosen = best
    if better:
        top = max(better, key=lambda c: c.inlier_ratio)
        gray = gray_level(moving.image, search.p_level, valid=moving.valid)
        chosen = Candidate(best.hypothesis, top.refined, top.evidence, search.agreement(top.refined.matrix, gray),
                           top.iterations)
        pool = [best, *check.alternatives(chosen)]
    moves = [(check.moved(chosen, c), c) for c in pool]
    shift, far = max(moves, key=lambda m: m[0])
    found = Settling(shift if shift > SHIFT_PX else 0.0, float(far.inlier_ratio), float(chosen.inlier_ratio),
                     taken=chosen is not best)
    rivals = [(d, c) for d, c in moves if c is not best and d > SHIFT_PX
              and c.inlier_ratio >= chosen.inlier_ratio - check.margin(chosen)]
    if not rivals:
        return chosen, found, None
    d, rival = max(rivals, key=lambda m: m[0])
    model = search.model
    wider = "" if model == "projective" else (f"; so does a motion no {model} one holds, where no alignment is right "
                                               "(a view tilted in depth: --model projective)")
    return chosen, found, RegistrationError(
        f"registration refused: the images do not pin the motion down: refined again from a start {NUDGE_PX:g} px off, "
        f"the alignment settled {d:.1f} px from the result with as many edge points lined up "
        f"({100 * rival.inlier_ratio:.1f}% against {100 * chosen.inlier_ratio:.1f}%): blurred, featureless or repetitive "
        f"content fits many motions{wider}")


class _Around:
    """The check's refinements and measures around a result: the moving cloud, the search whose refinement it
    repeats, the test that measures, the moving image's shape."""

    def __init__(self, moving, search, test, shape: tuple[int, ...]) -> None:
        self.moving, self.search, self.test, self.shape = moving, search, test, shape
        level = min(1, len(moving) - 1, len(test.reference) - 1)
        self.points = moving[level].points  # the edge points whose moves are read, at level 1 as the model check reads them
        self.size = test.reference.image.shape[:2]

    def alternatives(self, result: Candidate) -> list[Candidate]:
        """``result`` refined again from each of :func:`nudges`'s starts and measured; a refinement that fails or
        degenerates is left out."""
        T, out = result.refined.matrix, []
        for move in nudges(self.search.model, self.shape):
            try:
                refined, iterations = self.search.refine(self.moving, T @ move, top=min(TOP_LEVEL, len(self.moving) - 1))
            except (RegistrationError, np.linalg.LinAlgError):
                continue
            if degeneracy(refined.matrix, self.shape) is None:
                out.append(Candidate(Hypothesis(result.generator, T @ move), refined,
                                     self.test.measure(self.moving, refined.matrix), float("nan"), iterations))
        return out

    def moved(self, a: Candidate, b: Candidate) -> float:
        """The largest move, from ``a`` to ``b``, of the moving edge points that ``a`` lands on the reference (px;
        :func:`~.plausibility.largest_move`)."""
        return largest_move(a.refined.matrix, b.refined.matrix, self.points, self.size)

    @staticmethod
    def margin(c: Candidate) -> float:
        """:data:`~.plausibility.SIGNIFICANCE` standard deviations of ``c``'s inlier ratio (binomial over its
        overlapping edge points)."""
        p, n = c.inlier_ratio, max(1, c.evidence.overlap_points)
        return SIGNIFICANCE * float(np.sqrt(p * (1.0 - p) / n))
