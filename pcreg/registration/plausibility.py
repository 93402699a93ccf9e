"""The plausibility test of :func:`~pcreg.registration.api.register`: the evidence that tells a true
alignment from chance, and the refusal of the rest.

Failure signal: the winner's ``inlier_ratio`` is the share of moving edge points, among those that land
on the reference image, with a reference edge point within ``inlier_tolerance`` px whose edge direction
agrees within 30° (measured at full resolution; on images whose full-resolution reference cloud hits
``reference_max_points``, at the finest level where it does not, with the tolerance scaled to it).
``chance_ratio`` is what unrelated content reaches at the same distances. Below ``min_inlier_ratio``
(see :data:`~pcreg.registration.config.DEFAULT_MIN_INLIER_RATIO`; None turns the test off), below :data:`CHANCE_FACTOR` x
``chance_ratio`` or within :data:`SIGNIFICANCE` standard deviations of it, when the moving image's edges run
one way (:data:`ONE_DIRECTION`) or turn onto themselves (:func:`turned_onto_itself`: a disk, rings; but for the
translation model), with fewer than 2% of the points on the reference (no overlap), or when the moving
image's mirror aligns clearly better (a score :data:`MIRROR_FACTOR` times as high, and more of its edge
points; asked of every model when the search ended unconvinced; under ``min_inlier_ratio``, the mirror's
alignment passes where the image's does not), :class:`~pcreg.errors.RegistrationError`
is raised with a one-line reason. Unrelated images, noise and mirror images are refused this way.
"""

from __future__ import annotations

import copy

import numpy as np

from ..errors import RegistrationError
from .global_search import Evidence, alignment_evidence
from .clouds import ImageCloud
from .pyramid import CloudPyramid
from .search import Candidate

MIRROR_FACTOR = 1.2
"""A moving image whose mirror scores (:attr:`~pcreg.registration.search.Candidate.score`) this much better
than itself, and aligns more of its edge points, is refused as a mirror image."""

MIRROR_OVERLAP = 0.5
"""The share of the moving image's edge points a convincing alignment must lay on the reference for the mirror
search to be passed over: a page of text mirrored and turned 37 degrees lined up 64% of the edge points it laid on
the reference (its lines of text), 20% of the image's, convincing, and was taken for a rigid motion."""

CHANCE_FACTOR = 2.0
"""A plausible alignment has at least this multiple of its chance level of inliers (true alignments
measured at >= 2.8x, unrelated content at about 1x)."""

SIGNIFICANCE = 5.0
"""A plausible alignment's inliers exceed what chance gives by at least this many standard deviations of
that count (binomial: ``n p (1 - p)`` for ``n`` overlapping edge points at the chance ratio ``p``): with few
edge points (small images, ``--levels 1``) twice chance is within reach of chance. Five, a rule: random
crops of the shared photographs (32 to 96 px, 40 pairs a size) reached at most 3.6 between different
photographs, and at least 7.5 between two crops of one place (docs/algorithms.md)."""


ONE_DIRECTION = 0.02
"""A moving image whose edges' weaker direction holds less than this share of the stronger (the smaller
eigenvalue of its edge normals' scatter matrix against the larger, :func:`edge_spread`) has edges that run
one way: stripes, a grating, rows of crops. Its motion along them is not determined, and a "best" alignment
there is arbitrary (a 7 px shift of stripes came out as a 180° turn). Measured at the level the test reads:
every shared CamVid and DAVIS frame (579) 0.09 at the least (kite-surf's sea), the shared photographs 0.22,
the procedural textures 0.47; stripes, gratings and wood grain with noise 0.0013 at the most. A fiftieth lies
between the two, 4.5 times under the least real frame (docs/algorithms.md)."""

#: Edge points a pyramid level needs for :func:`edge_spread` to read it.
SPREAD_POINTS = 100


def edge_spread(cloud: CloudPyramid) -> float | None:
    """How far an image's edges run in more than one direction: the smaller eigenvalue of its edge normals'
    scatter matrix over the larger (1: every direction alike, 0: one direction), at the coarsest level with
    :data:`SPREAD_POINTS` edge points (noise scatters the normals of the finest; the coarser levels show the
    structure); None without such a level."""
    for level in range(len(cloud) - 1, -1, -1):
        n = cloud[level].normals
        if len(n) >= SPREAD_POINTS:
            low, high = np.linalg.eigvalsh(n.T @ n / len(n))
            return float(low / high) if high > 0 else 0.0
    return None


#: The turns about the edges' centre at which :func:`turned_onto_itself` reads an image: no two of them a multiple
#: of one angle a shape of few sides repeats at (a square's 90 degrees, a hexagon's 60), so that only a shape that
#: turns onto itself at every angle (a disk, rings) meets all three.
SELF_TURNS = (17.0, 41.0, 73.0)
SELF_TURN_UNMATCHED = 0.02
"""A moving image of which fewer than this share of edge points leave its own edges when turned
(:func:`turned_onto_itself`) has a rotation that is not determined, and is refused (but by the translation model):
the share of a cloud's points the test asks at the least of an alignment's overlap (the 2% of its edge points that
must land on the reference). ``tools/measure_self_turns.py``: of every shared CamVid and DAVIS frame and
photograph at most 0.105 land, of a disk, rings or a disk with noise at least 0.991 (docs/algorithms.md)."""

#: The edge points of a level :func:`turned_onto_itself` turns (drawn at random, seeded), onto every edge point.
SELF_TURN_SAMPLE = 1000


def turned_onto_itself(cloud: CloudPyramid) -> float | None:
    """The share of an image's edge points that land on its own edges turned about their centre
    (:func:`self_turn_share`), at the first level where all but :data:`SELF_TURN_UNMATCHED` of them land: its rotation
    is not determined; None where no level is so. Read from level 1 (noise scatters the finest level's edges; level 0
    only where level 1 holds fewer than :data:`SPREAD_POINTS` edge points) up to the last with :data:`SPREAD_POINTS`,
    each level with every edge point."""
    turned = _turned(cloud)
    return None if turned is None else turned[0]


def _turned(cloud: CloudPyramid) -> tuple[float, np.ndarray] | None:
    """:func:`turned_onto_itself`'s share and the centre (x, y) its level's edges turn about."""
    first = 1 if len(cloud) > 1 and len(cloud[1]) >= SPREAD_POINTS else 0
    for level in range(first, len(cloud)):
        c = cloud.every_point(level)
        if c is None or len(c) < SPREAD_POINTS:
            break
        landed = self_turn_share(c, level, stop=1.0 - SELF_TURN_UNMATCHED)
        if landed > 1.0 - SELF_TURN_UNMATCHED:
            return landed, c.points.mean(axis=0)
    return None


def self_turn_share(c: ImageCloud, level: int, *, stop: float | None = None) -> float:
    """The least share, over the turns of :data:`SELF_TURNS` about their centre, of :data:`SELF_TURN_SAMPLE` of the
    edge points of ``c`` (a pyramid ``level``'s every edge point; drawn at random, seeded) that land on its edges
    (within 1 px of the level and 30 degrees, as an alignment's inliers are counted); the first share at or under
    ``stop`` where given."""
    from scipy.spatial import cKDTree

    centre, tree = c.points.mean(axis=0), cKDTree(c.points)
    pick = np.random.default_rng(level).choice(len(c), min(len(c), SELF_TURN_SAMPLE), replace=False)
    h, w = c.shape
    landed = 1.0
    for angle in SELF_TURNS:
        t = np.deg2rad(angle)
        R = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
        p = (c.points[pick] - centre) @ R.T + centre
        inside = (p[:, 0] >= -0.5) & (p[:, 0] <= w - 0.5) & (p[:, 1] >= -0.5) & (p[:, 1] <= h - 0.5)
        dist, idx = tree.query(p[inside], k=1, distance_upper_bound=2.0**level)
        ok = np.isfinite(dist)
        cos = np.einsum("ij,ij->i", c.normals[pick][inside][ok] @ R.T, c.normals[idx[ok]])
        landed = min(landed, np.count_nonzero(cos >= np.cos(np.deg2rad(30.0))) / max(int(inside.sum()), 1))
        if stop is not None and landed <= stop:
            break
    return landed


#: The end of every refusal: the way past the test for images known to show one scene. Neighbouring frames of a
#: camera driving forward fit no global motion (CamVid's street frames, refused as rigid and as similarity) and are
#: what the dense field registers, past this test.
KNOWN = ("; frames known to show one scene (neighbours in a video, a camera moving forward) are registered without this "
         "test: min_inlier_ratio=0 (--min-inlier-ratio 0), with --model dense for a scene that moves in depth")


class Plausibility:
    """Measures alignments onto ``reference`` and tests the winner (see the module's description).

    tree : the reference cloud's index per level (:meth:`~pcreg.registration.refine.CoarseToFine.tree`).
    """

    def __init__(self, reference: CloudPyramid, tree, *, model: str, min_inlier_ratio: float | None,
                 inlier_tolerance: float, reference_max_points: int | None):
        self.reference, self.tree, self.model = reference, tree, model
        self.min_inlier_ratio, self.inlier_tolerance = min_inlier_ratio, inlier_tolerance
        # The evidence is measured at full resolution, unless the reference cloud had to be capped there (a
        # random subset of the edges leaves gaps that true matches fall into): then at the finest level with
        # every edge, with the tolerance scaled to that level (1 px at level 1 = 2 px).
        self.level = 0
        if reference_max_points is not None:
            while self.level < len(reference) - 1 and len(reference[self.level]) >= reference_max_points:
                self.level += 1

    def _motion(self, shape: tuple[int, ...] | None = None) -> str:
        """The motion a refusal names; for the models without a scale, the model that has one; for those with one,
        the scales the search reaches (Fourier-Mellin's 0.5-2: views of CamVid frames at 0.55-1.8 registered, at
        0.3-0.45 and 2.2-3 refused); for images of sizes further apart than that (``shape``: the moving
        image's), their sizes (:meth:`_sizes`)."""
        sizes = self._sizes(shape)
        if self.model == "rigid":
            return ("rigid motion (the similarity model also allows a change of scale, as a camera moving forward makes)"
                    + sizes)
        if self.model == "translation":
            return "translation (the rigid and similarity models also allow a rotation and a change of scale)" + sizes
        if sizes:
            return f"{self.model} motion{sizes}"
        return (f"{self.model} motion, or show it at scales more than about 2x apart, which the search does not "
                f"reach (if one is a close-up of the other, shrink the close-up by about that ratio first)")

    def _a_motion(self, shape: tuple[int, ...] | None = None) -> str:
        """:meth:`_motion` after its article ("an affine motion")."""
        from .transforms import with_article

        return with_article(self._motion(shape))

    def _sizes(self, shape: tuple[int, ...] | None) -> str:
        """A note for a refusal of images whose sizes differ by more than the search's scales reach (about 2x a
        side, :meth:`_motion`), else ''. It names the ratio of the images' sizes, which is the scene's scale between
        them only when both show all of it (not when one is a crop of the other)."""
        if shape is None:
            return ""
        (hr, wr), (hm, wm) = self.reference.image.shape[:2], shape[:2]
        apart = max(hr / hm, hm / hr, wr / wm, wm / wr)
        if apart <= 2.0:
            return ""
        return (f" (the images are {wr}x{hr} and {wm}x{hm} px, their sizes {apart:.1f}x apart: if the scene's scale "
                f"differs as much between them, more than about 2x apart, which the search does not reach, resize the "
                f"larger image first)")

    def off(self) -> Plausibility:
        """This test with its threshold off (``min_inlier_ratio=None``): it refuses only what it refuses whatever
        the threshold (a transform no view can have, too few edge points, no overlap)."""
        off = copy.copy(self)
        off.min_inlier_ratio = None
        return off

    @property
    def convincing(self) -> float:
        """The inlier ratio at which the search stops early: max(0.6, 2 x ``min_inlier_ratio``)."""
        return 0.6 if self.min_inlier_ratio is None else max(0.6, 2.0 * self.min_inlier_ratio)

    def measure(self, moving: CloudPyramid, T: np.ndarray, level: int | None = None) -> Evidence:
        """The evidence of ``T`` (``T_ref_mov``) aligning ``moving``'s cloud with the reference's (at the test's
        level, or at ``level``, the tolerance scaled to it)."""
        level = self.level if level is None else level
        return alignment_evidence(T, moving[level], self.reference[level], self.tree(level),
                                  tolerance=self.inlier_tolerance * 2**level)

    def worth_a_mirror(self, tried: list[Candidate], convincing: bool) -> bool:
        """Whether the search ended unconvinced (below the threshold too: a mirror image's own best alignment
        may be no better than unrelated content's), or convinced by an alignment over less than
        :data:`MIRROR_OVERLAP` of the moving image (the caller tells ``convincing`` so): then the moving image may
        be a mirror image of the reference (its mirror, if so, aligns better, :meth:`check`). Every model is asked: a rigid or
        similarity motion cannot mirror, and an affine or projective one, which could, starts from the
        search's rotations and refines to one, never to a mirror (a mirrored transform is refused anyway,
        :func:`~pcreg.registration.transforms.degeneracy`): a photograph's round outline or frame lines up
        rotated while its content does not."""
        return self.min_inlier_ratio is not None and not convincing

    def _content_turns(self, best: Candidate, moving: CloudPyramid, centre: np.ndarray) -> bool:
        """Whether the content of a moving image whose edges turn onto themselves at some level (a round field of
        view, a plate; :func:`turned_onto_itself`) tells its rotation all the same: ``best`` turned by each of
        :data:`SELF_TURNS` about ``centre`` aligns fewer than half the edge points ``best`` aligns (a disk's turned
        alignment aligns as many: its rotation is not determined)."""
        from .transforms import about_point, rigid2d

        T, half = best.refined.matrix, best.inlier_ratio / 2.0
        return all(self.measure(moving, T @ about_point(rigid2d(angle), tuple(centre))).inlier_ratio < half
                   for angle in SELF_TURNS)

    def _mirrored(self, mirror: Candidate, best: Candidate) -> bool:
        """Whether the moving image is a mirror image of the reference, its mirror's best alignment ``mirror``
        against its own ``best``: above the threshold, the mirror scores :data:`MIRROR_FACTOR` times as high and
        aligns more edge points; below it (where both may be no better than unrelated content), the mirror's
        alignment would pass the threshold and the chance test, the image's would not."""
        mir = self.min_inlier_ratio
        if mir is None:
            return False
        if best.inlier_ratio >= mir:
            return mirror.score > MIRROR_FACTOR * best.score and mirror.inlier_ratio > best.inlier_ratio
        return mirror.inlier_ratio >= mir and mirror.inlier_ratio >= CHANCE_FACTOR * mirror.evidence.chance_ratio

    def check(self, best: Candidate, *, mirror: Candidate | None = None, shape: tuple[int, ...] | None = None,
              moving: CloudPyramid | None = None) -> Evidence:
        """``best``'s evidence, or a :class:`RegistrationError` saying why it is refused. A transform that
        cannot be a view of a moving image of ``shape`` (:func:`~pcreg.registration.transforms.degeneracy`)
        is refused whether the test is on or off (``min_inlier_ratio=None``)."""
        from .transforms import degeneracy

        why = None if shape is None else degeneracy(best.refined.matrix, shape)
        if why is not None:
            raise RegistrationError(f"registration refused: {why}")
        ev, ratio = best.evidence, best.inlier_ratio
        need = max(10, int(np.ceil(0.02 * ev.moving_points)))
        if best.refined.fitness != 0.0 and ev.moving_points < need:
            raise RegistrationError(f"registration refused: the moving image has only {ev.moving_points} edge points "
                                    f"(at least {need} needed){self._sizes(shape)}")
        if best.refined.fitness == 0.0 and ev.overlap_points >= need:  # on the reference, matched to nothing
            raise RegistrationError(f"registration refused: no moving edge point came within the correspondence distance "
                                    f"of a reference edge point, though {ev.overlap_points} of {ev.moving_points} land "
                                    "on the reference: the images do not match there, or the distance is too small "
                                    "(--max-distance, max_correspondence_distance)")
        if best.refined.fitness == 0.0 or ev.overlap_points < need:
            raise RegistrationError(f"registration found no overlap between the images: {ev.overlap_points} of "
                                    f"{ev.moving_points} moving edge points land on the reference (at least {need} needed)"
                                   f"{self._sizes(shape)}")
        if mirror is not None and self._mirrored(mirror, best):
            raise RegistrationError(
                f"registration refused: the moving image is a mirror image of the reference (its mirror aligns "
                f"{100 * mirror.inlier_ratio:.1f}% of the edge points within {self.inlier_tolerance:g} px, the image "
                f"itself {100 * ratio:.1f}%" + (", with intensities agreeing less)" if ratio >= (self.min_inlier_ratio or 0.0)
                                                 else ")") + self._sizes(shape))  # 3x apart, neither aligns: both said
        mir, chance = self.min_inlier_ratio, ev.chance_ratio
        spread = None if moving is None or mir is None or mir <= 0 else edge_spread(moving)
        if spread is not None and spread < ONE_DIRECTION:
            raise RegistrationError(
                f"registration refused: the moving image's edges run one way (their second direction holds "
                f"{100 * spread:.1f}% of the first; stripes, a grating): its motion along them is not determined")
        turned = None if moving is None or spread is None or self.model == "translation" else _turned(moving)
        if turned is not None and moving is not None and not self._content_turns(best, moving, turned[1]):
            landed = turned[0]
            raise RegistrationError(
                f"registration refused: the moving image's edges turn onto themselves (turned by "
                f"{', '.join(f'{a:g}' for a in SELF_TURNS[:-1])} and {SELF_TURNS[-1]:g} degrees about their centre, "
                f"{100 * landed:.1f}% of them land on its own edges; a disk, rings): its rotation is not "
                "determined (the translation model registers its shift)")
        if mir is not None and mir > 0 and ratio < CHANCE_FACTOR * chance:
            raise RegistrationError(
                f"registration refused: the best alignment's {100 * ratio:.1f}% of tight, direction-consistent edge "
                f"points is under {CHANCE_FACTOR:g}x chance ({100 * chance:.1f}% expected from unrelated content at "
                f"the same distances); the images do not show the same scene under {self._a_motion(shape)}{KNOWN}")
        n = ev.overlap_points
        sd = float(np.sqrt(n * chance * (1.0 - chance)))
        if mir is not None and mir > 0 and ratio * n - chance * n < SIGNIFICANCE * sd:
            raise RegistrationError(
                f"registration refused: the best alignment's {ratio * n:.0f} tight, direction-consistent edge points "
                f"of {n} are within {SIGNIFICANCE:g} standard deviations of chance ({chance * n:.0f} ± {sd:.0f} "
                f"expected from unrelated content): too few edges to tell the same scene from another"
                f"{self._sizes(shape)}{KNOWN}")
        if mir is not None and ratio < mir:
            raise RegistrationError(
                f"registration refused: the best alignment puts only {100 * ratio:.1f}% of the overlapping edge "
                f"points within {self.inlier_tolerance:g} px of a reference edge of the same direction "
                f"(min_inlier_ratio {mir:g}); the images do not show the same scene under {self._a_motion(shape)}{KNOWN}")
        return ev


#: The model a registration's result is checked against (:func:`model_fit`), and the models narrower than it.
RICHER_MODEL = "projective"
NARROWER = ("translation", "rigid", "similarity", "affine")

SHIFT_PX = 3.0
"""A result is marked when the richer model, aligning significantly more edge points, moves some of them by
more than this (px at full size): the distance within which ``tools/bench_warped_photos.py`` counts a
registration right. The refinement runs at half size, where the tolerance is 2 px: the richer model moved the
edges of views the model makes by up to 2.1 px there (5 of 73 such results marked at 2 px, none at 2.5 or 3;
docs/algorithms.md)."""


FAR_PX = 10.0
"""A result is marked, whatever the gain's significance, when the richer model aligns at least as many edge points
and moves some of them by more than this (px at full size): the edges do not hold the result within it. On the
random views of the shared photographs (450 registrations by rigid, similarity and affine, docs/algorithms.md)
the richer model moved the edges of right results by 4.1 px at most; a real aerial pair registered by the rigid
model 22 px off (a 4% stretch across it), the richer model aligning 25.6% against 20.4% (3.3 standard deviations)
and moving edges 27.8 px, was returned trusted. Ten: the bound within which the docs count an unmarked result."""


def model_fit(best: Candidate, moving: CloudPyramid, richer, test: Plausibility, shape: tuple[int, ...], *,
              starts: tuple[np.ndarray, ...] = ()):
    """Whether ``best``'s model fits the images: its transform refined by ``richer`` (a
    :class:`~pcreg.registration.refine.CoarseToFine` of :data:`RICHER_MODEL`) at pyramid level 1 (twice its
    gate, then its gate, as a start is refined there) and both transforms measured there as ``test`` measures
    (:meth:`Plausibility.measure`, the tolerance scaled to the level). The model does not fit when the richer
    transform's inlier ratio exceeds the result's by :data:`SIGNIFICANCE` standard deviations of it (binomial,
    over the result's overlapping edge points there) and moves some of the moving edge points that land on
    the reference by more than :data:`SHIFT_PX`: a perspective view registered by a similarity, whose best
    similarity leaves its far side pixels off. Views that the model makes gain nothing (docs/algorithms.md). Nor
    does it when the richer transform aligns at least as many and moves some by more than :data:`FAR_PX`.

    starts : further starts of the richer refinement, T_ref_mov of the richer model (ORB's homography): a
        result far from the alignment (a wrong one) is not near the richer fit that would show it; the richer
        transform that aligns the most edge points is the one compared. A start that moves none of those edge
        points by more than :data:`SHIFT_PX` from the result is the result to the check's own tolerance: it is
        not refined again (refined, it ended within 1.1 px of the result's refinement on the 33 such pairs of
        the registration benchmark, docs/benchmarks.md).
    Returns a :class:`~pcreg.registration.result.ModelFit`, or None where every richer refinement fails or
    degenerates (nothing is said then)."""
    from .result import ModelFit
    from .transforms import apply

    level = min(1, len(moving) - 1, len(test.reference) - 1)
    if len(moving[level]) < 3 or len(test.reference[level]) < 3:
        return None
    T = best.refined.matrix
    points = moving[level].points
    here = apply(T, points)
    h, w = test.reference.image.shape[:2]
    lands = (here[:, 0] >= 0) & (here[:, 0] <= w - 1) & (here[:, 1] >= 0) & (here[:, 1] <= h - 1)
    points, here = points[lands], here[lands]
    # not all within SHIFT_PX: a start that sends a landing point to infinity or NaN is far from the result
    further = [S for S in starts if not np.all(np.linalg.norm(apply(S, points) - here, axis=1) <= SHIFT_PX)]
    richest = None
    for start in (T, *further):
        R = _richer_fit(richer, moving, start, level, shape)
        if R is not None:
            ev = test.measure(moving, R, level)
            if richest is None or ev.inlier_ratio > richest[1].inlier_ratio:
                richest = (R, ev)
    if richest is None:
        return None
    R, other = richest
    own = test.measure(moving, T, level)
    p, n = own.inlier_ratio, max(1, own.overlap_points)
    shift = largest_move(T, R, points, (h, w))
    return ModelFit(RICHER_MODEL, float(other.inlier_ratio), float(p), shift, fits=fits(p, other.inlier_ratio, n, shift),
                    starts=1 + len(further))


def fits(own: float, richer: float, n: int, shift: float) -> bool:
    """:func:`model_fit`'s verdict: whether a result whose inlier ratio is ``own`` over ``n`` overlapping edge points
    fits, the richer model's transform reaching ``richer`` and moving some of those points by ``shift`` px."""
    gain = richer - own > SIGNIFICANCE * np.sqrt(own * (1.0 - own) / max(1, n))
    return not (gain and shift > SHIFT_PX or richer >= own and shift > FAR_PX)


def largest_move(T: np.ndarray, R: np.ndarray, points: np.ndarray, size: tuple[int, int]) -> float:
    """The largest distance (px) between where ``T`` and ``R`` put those of ``points`` that ``T`` lands on an image of
    ``size`` (H, W): how far ``R`` moves the edge points that ``T`` aligns (0 without such points; a move that is not
    finite is left out)."""
    from .transforms import apply

    h, w = size
    here = apply(T, points)
    lands = (here[:, 0] >= 0) & (here[:, 0] <= w - 1) & (here[:, 1] >= 0) & (here[:, 1] <= h - 1)
    moved = np.linalg.norm(apply(R, points[lands]) - here[lands], axis=1)
    return float(np.max(moved, initial=0.0, where=np.isfinite(moved)))


def _richer_fit(richer, moving: CloudPyramid, start: np.ndarray, level: int, shape: tuple[int, ...]):
    """``start`` refined by ``richer`` at ``level`` (twice its gate, then its gate); None where the
    refinement fails or degenerates."""
    from .transforms import degeneracy

    R = start
    gate = richer.max_correspondence_distance * 2**level
    try:
        for dist in (2 * gate, gate):
            R = richer.at_level(moving, R, level, dist=dist, final=False).matrix
    except (RegistrationError, np.linalg.LinAlgError):
        return None
    return None if degeneracy(R, shape) is not None else R
