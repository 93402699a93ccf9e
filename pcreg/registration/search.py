"""The global search of :func:`~pcreg.registration.api.register`: hypotheses from the generators, each
refined coarse to fine and measured, in turn until one is convincing.

Generators (:mod:`pcreg.registration.global_search`): ``"fourier_mellin"`` takes the rotation from the
log-polar magnitude spectra and the translation from a phase correlation of the intensity images;
``"edges"`` rotates the moving edge cloud every ``angle_step`` degrees over the full circle and finds
each rotation's translation by FFT cross-correlation (the ``n_candidates`` best get a short ICP at the
search level, the coarsest with at least 100 points a side, and are ranked by their tight inliers
there); ``"orb"`` matches ORB features at pyramid level 1 and fits a similarity by RANSAC. Intensity
hypotheses (the 180° twin of Fourier-Mellin's included) are ranked by the normalised cross-correlation
of the images they align and the best refined at full resolution (a first pass with twice the correspondence
distance), Fourier-Mellin's second too when the first is not convincing; the edge hypothesis from the
coarsest level. Every ICP step uses the registration's backend;
the refined hypothesis is measured at full resolution (:class:`~pcreg.registration.global_search.Evidence`).

A generator is convincing when its refined hypothesis reaches an inlier ratio of max(0.6, 2 x
``min_inlier_ratio``) and its intensities agree (:data:`CONVINCING_NCC`); otherwise the next one runs,
so easy pairs pay for one. The winner has the most inliers, weighted by the intensities' agreement
(:attr:`Candidate.score`: edges alone cannot tell a brick wall from its copy shifted by a brick).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np

from ..errors import RegistrationError
from .global_search import (edge_canvas, Evidence, OrbMatches, alignment_evidence, edge_fft_hypotheses, fourier_mellin_hypotheses,
                            gray_level, orb_fit, orb_matches, photometric_agreement)
from .pyramid import CloudPyramid
from .refine import CoarseToFine, Refinement
from .result import IcpIteration
from .transforms import apply, corners

START_LEVEL = 0
"""Pyramid level at which rigid intensity hypotheses (within a few pixels) are refined first: full
resolution, measured 6-10% faster than level 1 and as accurate."""
SEARCH_MAX_CANVAS = 3072
"""The largest side of a global search's square canvas (Fourier-Mellin's, the edge search's), whatever the
pyramid's levels: a canvas is the long side squared (a 20000x20 strip at level 1 took 5.4 GB and 29 s; a 9600x720
panorama at full resolution 6.1 GB and 151 s). 3072 is the side the default four levels give the edge search at
level 3 for an image 16384 px long (Fourier-Mellin's: 2048). Under that length, the searches change only where
the edge search goes finer than level 3 for want of edge points (a sparse image) or fewer levels are asked for:
there its cells are larger than the level's pixels (a sparse 6000x2400 image: the same matrix in 11 s, not 76)."""
CONVINCING_NCC = 0.6
"""The search stops early only at an alignment whose intensities also agree (normalised cross-correlation at
pyramid level 2 at least this); otherwise every generator runs and the best one wins."""


@dataclass(frozen=True)
class Hypothesis:
    """A generator's starting point: ``matrix`` (``T_ref_mov``), refined coarse to fine from level ``top``
    (None: the coarsest)."""

    generator: str
    matrix: np.ndarray
    top: int | None = None


@dataclass(frozen=True)
class Candidate:
    """A hypothesis refined and measured: its refinement, the refined alignment's evidence and, where
    measured, the normalised cross-correlation of the intensities it aligns (NaN otherwise); where the
    search kept them (``GlobalSearch(keep_iterations=True)``), the refinement's ICP iterations."""

    hypothesis: Hypothesis
    refined: Refinement
    evidence: Evidence
    photometric_ncc: float = float("nan")
    iterations: tuple[IcpIteration, ...] = ()

    @property
    def generator(self) -> str:
        return self.hypothesis.generator

    @property
    def inlier_ratio(self) -> float:
        return self.evidence.inlier_ratio

    @property
    def score(self) -> float:
        """The inlier ratio weighted by the agreement of the intensities, when measured: edges rank,
        intensities break the ties of patterns."""
        ratio, ncc = self.inlier_ratio, self.photometric_ncc
        return ratio * (0.25 + max(ncc, 0.0)) if np.isfinite(ncc) else ratio


def unseen(hyps: list[np.ndarray], seen: list[np.ndarray], shape, *, min_px: float) -> list[np.ndarray]:
    """The hypotheses whose corners are more than ``min_px`` from those of every one in ``seen`` and
    of every earlier one in ``hyps``."""
    c = corners(shape)
    out: list[np.ndarray] = []
    for h in hyps:
        pc = apply(h, c)
        if all(np.max(np.linalg.norm(pc - apply(q, c), axis=1)) > min_px for q in list(seen) + out):
            out.append(h)
    return out


class GlobalSearch:
    """The generators in turn on one reference (see the module's description).

    refiner : the registration's coarse-to-fine ICP (its reference pyramid is the search's).
    measure : the evidence of an alignment of a moving pyramid (the plausibility test's measure).
    convincing : the inlier ratio at which a generator's refined hypothesis ends the search.
    keep_iterations : keep each candidate's ICP iterations (:attr:`Candidate.iterations`), for a caller
        that reports the winner's: the search refines it once, instead of again with a callback.
    """

    def __init__(self, refiner: CoarseToFine, measure: Callable[[CloudPyramid, np.ndarray], Evidence], *,
                 model: str, generators: Sequence[str], angle_step: float, n_candidates: int, seed: int,
                 convincing: float, keep_iterations: bool = False):
        self.refiner, self.reference, self.measure = refiner, refiner.reference, measure
        self.keep_iterations = keep_iterations
        self.model, self.generators, self.seed, self.convincing = model, tuple(generators), seed, convincing
        self.angle_step, self.n_candidates = angle_step, n_candidates
        self.collapsed: list[str] = []  # the last run's hypotheses whose refinement failed, and why
        self.search_model = "translation" if model == "translation" else "rigid"
        self.levels = len(self.reference)
        self.p_level = min(2, self.levels - 1)
        self.reference_gray, _ = gray_level(self.reference.image, self.p_level, valid=self.reference.valid)
        self._matched: list[tuple[CloudPyramid, int, OrbMatches | None]] = []

    def orb_matches(self, moving: CloudPyramid, level: int) -> OrbMatches | None:
        """ORB's matches of ``moving``'s image with the reference's at pyramid ``level``
        (:func:`~pcreg.registration.global_search.orb_matches`), computed once per moving pyramid and level: the
        ORB generator's, and a check's of the same pair at the same level."""
        for pyramid, at, matches in self._matched:
            if pyramid is moving and at == level:
                return matches
        matches = orb_matches(self.reference.image, moving.image, level=level, reference_valid=self.reference.valid,
                              moving_valid=moving.valid)
        self._matched.append((moving, level, matches))
        return matches

    def run(self, moving: CloudPyramid) -> list[Candidate]:
        """Every generator in turn until one is convincing: the refined hypotheses, in the order tried. A
        hypothesis whose refinement fails (a similarity that shrinks the moving image to a point) is left
        out, its reason kept in ``collapsed`` (this run's), and the next generator tried."""
        gray = gray_level(moving.image, self.p_level, valid=moving.valid)
        tried: list[Candidate] = []
        self.collapsed = []
        for generator in self.generators:
            if generator == "edges":
                hyps = [self.edge_hypothesis(moving)]
            else:
                hyps = self.intensity_hypotheses(generator, moving, gray, seen=[c.refined.matrix for c in tried])
            for h in hyps[:2 if generator == "fourier_mellin" else 1]:  # Fourier-Mellin's 180° twin too
                try:
                    tried.append(self.evaluate(h, moving, gray))
                except RegistrationError as exc:  # its refinement collapsed: no alignment, the next one's may be
                    self.collapsed.append(f"{generator}'s: {exc}")
                    continue
                if self.is_convincing(tried[-1]):
                    return tried
        return tried

    def nothing_refined(self) -> RegistrationError:
        """Why the last run (or the one hypothesis ``init`` gave, which raises itself) left no candidate: every
        hypothesis's refinement failed, or the generators made none."""
        if self.collapsed:
            return RegistrationError(f"registration refused: every hypothesis's refinement failed "
                                     f"({'; '.join(self.collapsed)})")
        return RegistrationError("no hypothesis could be generated (too few edges and features in the images)")

    def is_convincing(self, c: Candidate) -> bool:
        return c.inlier_ratio >= self.convincing and c.photometric_ncc >= CONVINCING_NCC

    def evaluate(self, h: Hypothesis, moving: CloudPyramid, gray, *, again: bool = False) -> Candidate:
        """``h`` refined coarse to fine and measured (edges and intensities). A similarity from an intensity
        generator (or, ``again``, any start) that the coarse levels leave unconvincing is refined once more from
        full resolution, as a rigid one is, and the better of the two kept: on small images (a 288x216 crop has
        about 125 edge points at level 3) the coarsest levels pulled starts 2-4 px from the truth 10-18 px away,
        and refusals of such views."""
        refined, iterations = self.refine(moving, h.matrix, top=h.top)
        ncc = self.agreement(refined.matrix, gray)
        c = Candidate(h, refined, self.measure(moving, refined.matrix), ncc, iterations)
        again = again or (h.generator in ("fourier_mellin", "orb") and self.model == "similarity")
        if h.top is None and again and not self.is_convincing(c):
            try:
                fine = self.evaluate(replace(h, top=START_LEVEL), moving, gray)
            except RegistrationError:  # its refinement collapsed: the coarse-to-fine one stands
                return c
            return fine if fine.score > c.score else c
        return c

    def refine(self, moving: CloudPyramid, T: np.ndarray, *, top: int | None = None
               ) -> tuple[Refinement, tuple[IcpIteration, ...]]:
        """``T`` refined coarse to fine, and its ICP iterations where the search keeps them (else ())."""
        kept: list[IcpIteration] = []
        refined = self.refiner.refine(moving, T, top=top, callback=kept.append if self.keep_iterations else None)
        return refined, tuple(kept)

    def agreement(self, T: np.ndarray, gray) -> float:
        mov_gray, mov_valid = gray
        return photometric_agreement(T, self.reference_gray, mov_gray, level=self.p_level, moving_valid=mov_valid)

    def edge_hypothesis(self, moving: CloudPyramid) -> Hypothesis:
        """Rotation samples every ``angle_step`` degrees: the best few get a short ICP at the search level
        and are ranked by their tight inliers there (ICP's fitness under its wide gate is near 1 for wrong
        hypotheses too); the best is refined from the coarsest level."""
        ref = self.reference
        g_level = min(3, self.levels - 1)
        # The search needs enough points to tell hypotheses apart: go finer until it has them.
        while g_level > 0 and (len(moving[g_level]) < 100 or len(ref[g_level]) < 100):
            g_level -= 1
        g_tree = self.refiner.tree(g_level)
        angles = np.array([0.0]) if self.model == "translation" else np.arange(0.0, 360.0, self.angle_step)
        # cells of the level's pixels, or larger where its canvas would pass SEARCH_MAX_CANVAS (a long strip's)
        cell = max(2.0**g_level, edge_canvas(ref[g_level].shape, 1.0) / SEARCH_MAX_CANVAS)
        Ts, score = edge_fft_hypotheses(ref[g_level], moving[g_level], angles=angles, cell=cell)
        best = (-1.0, None)
        for k in np.argsort(-score)[:self.n_candidates]:
            Tk = self.refiner.at_level(moving, Ts[k], g_level, dist=3.0 * cell, model=self.search_model,
                                       final=False).matrix
            sc = alignment_evidence(Tk, moving[g_level], ref[g_level], g_tree, tolerance=2.0**g_level).inlier_ratio
            if sc > best[0]:
                best = (sc, Tk)
        return Hypothesis("edges", best[1])

    def intensity_hypotheses(self, generator: str, moving: CloudPyramid, gray, *,
                             seen: list[np.ndarray]) -> list[Hypothesis]:
        """Fourier-Mellin's or ORB's hypotheses, the best by intensity first; none of those that would land
        within 2 px of an alignment in ``seen``. The search refines the first, and Fourier-Mellin's second (its
        first's 180° twin) when the first is not convincing: the intensities of two small, blurred views that
        overlap by a third favoured the twin turned by 180° (about 330 px off on a 200x150 view, 46% of its edge
        points within the tolerance, and trusted), while the other lined up 88% of them.

        They are usually within a few pixels: refined at full resolution alone (a first pass with twice
        the correspondence distance), where the coarse levels of fine repetitive patterns (bricks) cannot
        pull them away. (A scale, or more, is estimated coarse to fine: a level-1 start leaves its bias.)
        """
        ref, mov = self.reference, moving
        # Fourier-Mellin on a canvas of about 256-320 px: level 1 for 512-640 px images, finer or coarser
        # for smaller or larger ones (its cost grows with the canvas area, its precision with the resolution).
        big = max(ref.image.shape[:2] + mov.image.shape[:2])
        fm_level = int(max(min(self.levels - 1, max(0, np.ceil(np.log2(big / 320.0)))), np.ceil(np.log2(big / SEARCH_MAX_CANVAS))))
        # ORB at level 1 for a motion of four parameters or fewer; an affine or projective fit of every
        # parameter at full resolution, where its matches measure a shear or a perspective term best
        orb_level = 0 if self.model in ("affine", "projective") else min(1, self.levels - 1)
        if generator == "fourier_mellin":
            hyps = fourier_mellin_hypotheses(ref.image, mov.image, level=fm_level,
                                             model=self.model if self.model in ("translation", "rigid") else "similarity",
                                             reference_valid=ref.valid, moving_valid=mov.valid)
        else:
            hyps = orb_fit(self.orb_matches(mov, orb_level),
                           model=self.model if self.model in ("affine", "projective") else self.search_model, seed=self.seed)
        hyps = unseen(hyps, seen, mov.image.shape, min_px=2.0)
        if not hyps:
            return []
        ranked = sorted(hyps, key=lambda H: -self.agreement(H, gray))  # stable: ties in the generator's order
        # The start level follows the hypothesis's precision: Fourier-Mellin's is about a cell of the
        # level it ran at (its rotation step is one row of its log-polar image).
        start = min(self.levels - 1, max(START_LEVEL, fm_level - 1)) if generator == "fourier_mellin" else START_LEVEL
        if self.model in ("translation", "rigid"):
            top: int | None = min(start, self.levels - 1)
        elif generator == "orb" and self.model in ("affine", "projective"):
            top = min(1, self.levels - 1)  # a fit of every parameter: the coarsest levels pulled it onto lines of text
        else:  # a scale, or more, coarse to fine
            top = None
        return [Hypothesis(generator, h, top) for h in ranked]
