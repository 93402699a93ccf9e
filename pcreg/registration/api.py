"""Registration: ``icp`` for point clouds (:mod:`.cloud_icp`, given here too), ``register`` for images.

Both run the ICP step of one backend (:func:`~pcreg.registration.steps.icp_step`): the reference ICP
(``backend="reference"``, :mod:`pcreg.registration.reference`) or Open3D's (``backend="open3d"``,
:mod:`pcreg.registration.open3d_icp`), and return the same :class:`~pcreg.registration.result.RegistrationResult`.
``register`` reads as its steps: cloud pyramids (:mod:`.pyramid`), the coarse-to-fine refinement
(:mod:`.refine`), the global search (:mod:`.search`) and the plausibility test (:mod:`.plausibility`).
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from .._calls import interrupts_unwrapped
from ..errors import InputError, RegistrationError
from ..frame import low_bits_note
from ..validation import check_callable, check_int, check_matrix
from .cloud_icp import check_init, icp, voxel_downsample
from .clouds import ImagePyramid, as_rgb_uint8, check_pyramid
from .config import DEFAULT_MIN_INLIER_RATIO, PyramidConfig, RegisterConfig
from .dense import DENSE_GLOBAL_MODEL, DenseIteration, DenseOptions, DenseReference, DenseRegistrationResult, GlobalStep, InitialGrid, finest_grid_shape, refine_field
from .dense.levels import check_prepared
from .features import feature_check
from .global_search import gray_level, orb_fit
from .inputs import check_cloud
from .plausibility import CHANCE_FACTOR, MIRROR_FACTOR, MIRROR_OVERLAP, NARROWER, RICHER_MODEL, Plausibility, model_fit
from .pyramid import CloudPyramid
from .refine import CoarseToFine
from .repetition import pair_repeats, said_with_repeats
from .result import IcpIteration, ImageEvidence, RegistrationResult
from .search import CONVINCING_NCC, START_LEVEL, Candidate, GlobalSearch, Hypothesis
from .steps import IcpSettings, icp_step
from .transforms import about_point, corners, image_center

__all__ = ["CHANCE_FACTOR", "CONVINCING_NCC", "DEFAULT_MIN_INLIER_RATIO", "MIRROR_FACTOR", "START_LEVEL",
           "check_cloud", "icp", "register", "register_dense", "voxel_downsample"]


# ---------------------------------------------------------------------------------------------------
# Images
# ---------------------------------------------------------------------------------------------------

def register(reference_image: np.ndarray, moving_image: np.ndarray, *, config: RegisterConfig = RegisterConfig(),
             model: str | None = None, backend: str | None = None, init: str | np.ndarray | None = None,
             reference_mask: np.ndarray | str | None = "auto", moving_mask: np.ndarray | str | None = "auto",
             reference_pyramid: ImagePyramid | None = None, moving_pyramid: ImagePyramid | None = None,
             callback: Callable[[IcpIteration], None] | None = None) -> RegistrationResult:
    """Register ``moving_image`` to ``reference_image``: the returned ``matrix`` is ``T_ref_mov``.

    Both images become edge clouds (:func:`pcreg.image_cloud`) at pyramid levels 0..levels-1
    (:class:`~pcreg.registration.pyramid.CloudPyramid`). With ``init="auto"`` (or ``"global"``) hypotheses
    come from the search's ``generators``, tried in order until one is convincing, each refined coarse to
    fine (:class:`~pcreg.registration.search.GlobalSearch`); ``init="identity"``, ``"center"`` (image
    centres aligned) or a 3x3 matrix replaces the search by that one hypothesis. The winner must pass the
    plausibility test (:mod:`pcreg.registration.plausibility`): unrelated images, noise and mirror images
    raise :class:`~pcreg.errors.RegistrationError` with a one-line reason. With the test and ``model_check`` on
    (the defaults), the winner is also refined again from two starts 6 px off (:mod:`pcreg.registration.settling`):
    a clearly better alignment beside it is taken in its place, and one as good elsewhere (the images do not
    determine the motion) raises :class:`~pcreg.errors.RegistrationError`.

    reference_image, moving_image : (H, W, 3) uint8 RGB (also gray, uint16, float in [0, 1]); the
        sizes may differ.
    config : the options, by step (:class:`~pcreg.registration.config.RegisterConfig`: the pyramid, the
        search, the ICP and its backend, the plausibility test), checked when the config was made.
        Its ``model="dense"`` returns the global similarity (this function, with the rest of the config)
        refined by a dense field (:func:`pcreg.register_dense`), a
        :class:`~pcreg.registration.dense.DenseRegistrationResult`.
    model, backend : shorthands for ``config.replace(model=..., backend=...)``; None keeps the config's.
    init : None keeps the config's ``search.init``; one of its names replaces it; a 3x3 ``T_ref_mov``
        is the one hypothesis, refined instead of searching (a transform the model can hold, as :func:`icp`'s):
        coarse to fine and, where the coarse levels leave it unconvincing, again from full resolution, the better
        kept (as the search's own starts are), so that a start at the answer is not pulled off it.
    reference_mask, moving_mask : usable pixels, ``"auto"`` (ignore black padding) or None; with
        ``model="dense"`` its global similarity's (the field always leaves black padding out).
    reference_pyramid, moving_pyramid : the images' :func:`~pcreg.registration.clouds.image_pyramid` (same ``levels``,
        ``sampler``, mask and ``canny_percentile``), when the caller keeps them to reuse (a frame of a
        stream is the moving image once and the reference once); None builds the clouds here. The
        clouds are the same (to OpenCV's float32 rounding of the gradient magnitude).
    callback : called with each :class:`~pcreg.registration.result.IcpIteration` of the winning
        hypothesis's refinement (the better alignment's, where the refine-again check took one), in order, once
        the search has chosen it (before the plausibility test),
        with the same numbers as without a callback; with ``model="dense"``, its global similarity's (the
        pyramids too are that step's).

    Returns a :class:`RegistrationResult` with ``inlier_ratio``, ``overlap`` and ``generator`` (which
    generator's hypothesis won, or ``"init"``) besides the ICP's own figures.
    """
    with interrupts_unwrapped():  # Ctrl-C in a compiled kernel: the KeyboardInterrupt, not numba's SystemError
        return _register(reference_image, moving_image, config=config, model=model, backend=backend, init=init,
                         masks=(reference_mask, moving_mask), pyramids=(reference_pyramid, moving_pyramid),
                         callback=callback, judged=False)[0]


def register_judged(reference_image: np.ndarray, moving_image: np.ndarray, *, config: RegisterConfig = RegisterConfig(),
                    backend: str | None = None, callback: Callable[[IcpIteration], None] | None = None,
                    reference_mask: np.ndarray | str | None = "auto", moving_mask: np.ndarray | str | None = "auto"
                    ) -> tuple[RegistrationResult, RegistrationError | None]:
    """:func:`register` with its plausibility test's refusal returned, from one search: ``(result, None)`` where
    :func:`register` returns ``result``; ``(pose, refusal)`` where it raises ``refusal``, ``pose`` as it returns it with
    the test off (``min_inlier_ratio=None``), whose refusals (a transform no view can have, too few edge points, no
    overlap) are raised. A cross-check reports a refused pair's poses so (:func:`pcreg.crosscheck`). The masks as
    :func:`register` takes them."""
    return _register(reference_image, moving_image, config=config, model=None, backend=backend, init=None,
                     masks=(reference_mask, moving_mask), pyramids=(None, None), callback=callback, judged=True)


def _register(reference_image, moving_image, *, config: RegisterConfig, model, backend, init, masks: tuple,
              pyramids: tuple, callback, judged: bool) -> tuple:
    """:func:`register`'s steps: the result and, ``judged``, the plausibility test's refusal (else raised)."""
    config = _configured(config, model=model, backend=backend, init=init)
    reference_mask, moving_mask = masks
    start_matrix = None if init is None or isinstance(init, str) else check_matrix(init, "init", 3)
    if start_matrix is not None and config.model != "dense":  # dense: its global step's model checks it
        check_init(start_matrix, config.model)
    if config.model == "dense":
        if any(m is not None and not isinstance(m, str) for m in (reference_mask, moving_mask)):
            raise InputError("the dense model cannot leave masked pixels out (it leaves black padding out): give "
                             "images without a mask (transparent pixels), or a global model")
        return _register_dense_model(reference_image, moving_image, config, start_matrix, masks=masks,
                                     pyramids=pyramids, callback=callback, judged=judged)
    ref_img, mov_img = as_rgb_uint8(reference_image, name="reference image"), as_rgb_uint8(moving_image, name="moving image")
    _check_inputs(ref_img, mov_img, config.pyramid, reference_mask, moving_mask, callback)
    start = time.perf_counter()
    p = config.pyramid
    reference, moving = _pyramids(ref_img, mov_img, *pyramids, levels=p.levels, sampler=p.sampler,
                                  canny_percentile=p.canny_percentile, seed=config.search.seed,
                                  masks=(reference_mask, moving_mask), max_points=(p.reference_max_points, p.max_points),
                                  given=(reference_image, moving_image))
    best, tried, mirror, test, search = _search(reference, moving, config, config.search.init if start_matrix is None
                                                else start_matrix, keep_iterations=callback is not None)
    settling, unsettled = None, None
    if _checked(config):  # refined again from starts a few px off: a better alignment taken, a valley refused
        from .settling import settle

        best, settling, unsettled = settle(best, moving, search, test, mov_img.shape)
    if callback is not None:
        for iteration in best.iterations:
            callback(iteration)
    try:
        evidence, refusal = test.check(best, mirror=mirror, shape=mov_img.shape, moving=moving), None
        if unsettled is not None:
            raise unsettled
    except RegistrationError as refused:  # judged: the pose as the test off returns it (what that refuses is raised)
        exc = said_with_repeats(refused, ref_img, mov_img) if config.plausibility.model_check else refused
        if not judged:
            raise exc.with_traceback(refused.__traceback__) from None  # where the test refused, kept
        evidence, refusal = test.off().check(best, shape=mov_img.shape, moving=moving), exc
    checks = _checks(reference, moving, config, best, test, search, mov_img.shape) if refusal is None else (None, None)
    checks = (*checks, settling, pair_repeats(ref_img, mov_img) if refusal is None and config.plausibility.model_check else None)
    return _result(best, evidence, tried, mirror, backend=config.backend, seconds=time.perf_counter() - start,
                   points=(len(moving[0]), len(reference[0])), checks=checks), refusal


def _checks(reference: CloudPyramid, moving: CloudPyramid, config: RegisterConfig, best: Candidate,
            test: Plausibility, search: GlobalSearch, shape: tuple[int, ...]) -> tuple:
    """With the test and ``model_check`` on ((None, None) otherwise): :func:`~.plausibility.model_fit` of a model
    narrower than the projective one (ORB's homography a second start: a wrong result is not near the projective
    fit that shows it), :func:`~.features.feature_check` of a projective result, which no richer model checks
    (run on every model it took two to four times the registration's time: docs/benchmarks.md). The model check
    shares the search's KD-trees of the reference and its ORB matches at level 1, where the search made them."""
    if not _checked(config):
        return None, None
    if config.model in NARROWER:
        # pcreg's own step (Open3D's has no projective model) onto the search's reference trees
        richer = _refiner(reference, config, RICHER_MODEL, "reference", trees=search.refiner.trees, dlt="normal")
        orb = orb_fit(search.orb_matches(moving, 1), model=RICHER_MODEL, seed=config.search.seed)
        return model_fit(best, moving, richer, test, shape, starts=tuple(orb)), None
    return None, feature_check(reference.image, moving.image, best.refined.matrix, reference_valid=reference.valid,
                               moving_valid=moving.valid, seed=config.search.seed)


def _checked(config: RegisterConfig) -> bool:
    """Whether a result is checked beyond the plausibility test (the test and ``model_check`` on)."""
    return config.plausibility.model_check and config.plausibility.min_inlier_ratio is not None


def _refiner(reference: CloudPyramid, config: RegisterConfig, model: str, backend: str, *,
             point_to_line: bool = False, trees: dict | None = None, dlt: str = "svd") -> CoarseToFine:
    """The coarse-to-fine ICP of ``model`` with ``backend``'s step onto ``reference``, with ``config``'s ICP options
    (``trees``: another refinement's KD-trees of ``reference``, shared; ``dlt``: the projective step's solve)."""
    icp = config.icp
    return CoarseToFine(reference, icp_step(backend),
                        settings=IcpSettings(model=model, relative_fitness=icp.relative_fitness, weights=icp.weights, dlt=dlt),
                        max_correspondence_distance=icp.max_correspondence_distance, iterations=icp.iterations,
                        relative_rmse=icp.relative_rmse, point_to_line=point_to_line, trees=trees)


def _configured(config: RegisterConfig, *, model: str | None, backend: str | None, init) -> RegisterConfig:
    """:func:`register`'s ``config`` with its shorthands (``model``, ``backend``, an ``init`` name) set in
    it: the one place they become options, checked by the config."""
    if not isinstance(config, RegisterConfig):
        raise InputError(f"config must be a pcreg.RegisterConfig, got {type(config).__name__}")
    changes = {name: value for name, value in (("model", model), ("backend", backend)) if value is not None}
    if isinstance(init, str):
        changes["init"] = init
    return config.replace(**changes) if changes else config


def _register_dense_model(reference_image, moving_image, config: RegisterConfig, start_matrix, *, masks: tuple,
                          pyramids: tuple, callback, judged: bool) -> tuple:
    """``model="dense"``: the global similarity (:func:`register`, with the rest of ``config``, the ``masks``
    (``"auto"`` or None), the images' ``pyramids`` and the ``callback``; ``judged``: its refusal returned, else
    raised), refined by a dense field
    (:func:`pcreg.register_dense`); returns its :class:`~pcreg.registration.dense.DenseRegistrationResult` and the
    refusal."""
    start, refusal = _register(reference_image, moving_image, config=config.replace(model=DENSE_GLOBAL_MODEL, model_check=False),
                               model=None, backend=None, init=start_matrix, masks=masks, pyramids=pyramids,
                               callback=callback, judged=judged)
    return register_dense(reference_image, moving_image, global_result=start,
                          options=DenseOptions(seed=config.search.seed, global_step=GlobalStep(backend=config.backend))), refusal


def register_dense(reference_image: np.ndarray, moving_image: np.ndarray, *, options: DenseOptions = DenseOptions(),
                   global_result: RegistrationResult | np.ndarray | None = None,
                   initial: DenseRegistrationResult | np.ndarray | None = None,
                   prepared: DenseReference | None = None,
                   callback: Callable[[DenseIteration], None] | None = None) -> DenseRegistrationResult:
    """Register ``moving_image`` to ``reference_image`` with a smooth dense field (:mod:`pcreg.registration.dense`).

    reference_image, moving_image : (H, W, 3) uint8 RGB of the same size (also gray, uint16, float).
    options : :class:`~pcreg.registration.dense.DenseOptions`, the dense step's and the global step's
        options (checked when made, and here against the images' size).
    global_result : the global step's result or a 3x3 ``T_ref_mov`` (refused when its horizon line crosses
        the images: pixels sent through infinity); None runs :func:`pcreg.register`
        with the options' :class:`~pcreg.registration.dense.GlobalStep` and ``seed`` (its :class:`~pcreg.errors.RegistrationError` propagates).
    initial : start from an earlier registration of the same reference (its result or its ``grid``),
        e.g. the previous video frame's: its displacements, added to *this* registration's global
        transform (give the earlier one's), start level ``options.initial_level`` with the gate
        ``radius``, and the coarser levels are skipped, so the frame may have moved ``radius *
        2^initial_level`` px (12) from the earlier field, against 48 px from the global transform. Same
        image size, ``finest_level`` and ``membrane.grid_spacing`` (the grid's shape is checked). Measured in use:
        :class:`pcreg.pipeline.stream.DenseStep`.
    prepared : ``reference_image`` prepared once for many registrations
        (:func:`~pcreg.registration.dense.prepare_reference` with the same options), which saves building
        its pyramid each time (a stream's key frame: :class:`pcreg.Propagator`); refused when it was made
        from another image. The same result as without it.
    callback : called with a :class:`~pcreg.registration.dense.DenseIteration` after every iteration.
    Returns a :class:`~pcreg.registration.dense.DenseRegistrationResult`.
    """
    t_start = time.perf_counter()
    ref = as_rgb_uint8(reference_image, name="reference image")
    mov = as_rgb_uint8(moving_image, name="moving image")
    if ref.shape != mov.shape:
        raise InputError(f"dense registration needs images of one size, got {ref.shape[:2]} and {mov.shape[:2]}")
    if not isinstance(options, DenseOptions):
        raise InputError(f"options must be a pcreg.DenseOptions, got {type(options).__name__}")
    options.check_shape(ref.shape)
    if prepared is not None:
        check_prepared(prepared, ref, options)
    check_callable(callback, "callback")
    start = _initial_grid(initial, ref.shape, options)
    with interrupts_unwrapped():  # Ctrl-C in a compiled kernel: the KeyboardInterrupt, not numba's SystemError
        global_result, given_seconds = _global_step(ref, mov, global_result, options)
        return refine_field(ref, mov, global_result, options, callback=callback, started=t_start,
                            given_seconds=given_seconds, initial=start, prepared=prepared)


def _initial_grid(initial, shape: tuple[int, ...], options: DenseOptions) -> InitialGrid | None:
    """``register_dense``'s ``initial``, checked against the images and options, starting at
    ``options.initial_level`` (at least ``finest_level``, capped at the coarsest level)."""
    if initial is None:
        return None
    level = min(check_int(options.initial_level, "initial_level", lo=options.finest_level, hi=7), options.levels - 1)
    if isinstance(initial, DenseRegistrationResult):
        if initial.grid is None:
            raise InputError("initial: this dense result carries no grid to start from")
        grid = initial.grid
    else:
        raw = np.asarray(initial) if isinstance(initial, (np.ndarray, list, tuple)) else None
        if raw is None or raw.dtype.kind not in "iuf":
            raise InputError("initial must be a DenseRegistrationResult or a numeric (rows, columns, 2) grid of "
                             "displacements")
        grid = raw
    expected = finest_grid_shape(shape, options)
    if grid.shape != (*expected, 2):
        raise InputError(f"initial: a grid of shape {grid.shape}, but a registration of {shape[1]}x{shape[0]} "
                         f"images at finest_level {options.finest_level} and grid_spacing "
                         f"{options.membrane.grid_spacing:g} has {expected[0]}x{expected[1]} nodes: it must come from "
                         "one of the same size and options")
    with np.errstate(over="ignore", invalid="ignore"):  # beyond float32: inf, refused below
        grid = np.array(grid, dtype=np.float32)
    if not np.all(np.isfinite(grid)):
        raise InputError("initial: the grid has non-finite displacements (or beyond float32's range)")
    return InitialGrid(grid, level)


def _given_global(global_result, shape: tuple[int, ...]) -> RegistrationResult:
    """A given global step (a result, or a 3x3 ``T_ref_mov``) as a :class:`RegistrationResult`, checked
    against images of ``shape``: a 3x3 matrix that keeps every moving pixel on this side of its horizon (a
    pixel sent through infinity has no place in the field)."""
    if isinstance(global_result, RegistrationResult):
        M = np.asarray(global_result.matrix, dtype=np.float64)
        if M.shape != (3, 3) or not np.all(np.isfinite(M)):
            raise InputError(f"global_result: a registration of shape {M.shape} (a 3-D cloud's?); an image "
                             "registration's T_ref_mov is a finite 3x3 matrix")
        _check_horizon(M, shape)
        return global_result
    if np.iscomplexobj(global_result):  # numpy would drop the imaginary parts with a warning
        raise InputError("global_result: complex numbers; give its real matrix")
    try:
        M = np.asarray(global_result, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("global_result must be a RegistrationResult or a finite invertible 3x3 matrix") from None
    if M.shape != (3, 3) or not np.all(np.isfinite(M)) or abs(np.linalg.det(M)) < 1e-12:
        raise InputError("global_result must be a RegistrationResult or a finite invertible 3x3 matrix")
    _check_horizon(M, shape)
    return RegistrationResult(matrix=M, fitness=float("nan"), inlier_rmse=float("nan"), iterations=0,
                              converged=True, backend="given", frames="T_ref_mov")


def _check_horizon(M: np.ndarray, shape: tuple[int, ...]) -> None:
    """Refuse a ``T_ref_mov`` whose horizon line (homogeneous w = 0) crosses or touches the moving image:
    the pixels beyond it would be sent through infinity, a field of inf and NaN."""
    w = np.concatenate([corners(shape), np.ones((4, 1))], axis=1) @ M[2]
    if not (np.all(w > 0) or np.all(w < 0)):
        raise InputError("global_result sends part of the moving image through infinity (its horizon line crosses "
                         "the image); no view of one scene in two images does that to a pixel seen in both")


def _global_step(ref: np.ndarray, mov: np.ndarray, global_result, options: DenseOptions
                 ) -> tuple[RegistrationResult, float]:
    """The global step: the given one (with its seconds, counted in the dense result's), or
    :func:`pcreg.register`'s with ``options``' global step (its time is inside the dense step's own)."""
    if global_result is not None:
        given = _given_global(global_result, mov.shape)
        return given, float(given.seconds)
    step = options.global_step
    return register(ref, mov, config=step.config(options.seed), init=step.start), 0.0


def _result(best: Candidate, evidence, tried: list[Candidate], mirror: Candidate | None, *, backend: str,
            seconds: float, points: tuple[int, int], checks: tuple = (None, None, None, None)) -> RegistrationResult:
    """The winner as a :class:`RegistrationResult`; ``info`` lists every hypothesis tried."""
    r = best.refined
    return RegistrationResult(
        matrix=r.matrix, fitness=r.fitness, inlier_rmse=r.inlier_rmse, iterations=r.iterations,
        converged=r.converged, backend=backend, seconds=seconds, frames="T_ref_mov",
        evidence=ImageEvidence(evidence.inlier_ratio, evidence.chance_ratio, evidence.overlap, best.generator, *checks),
        info={"moving_points": points[0], "reference_points": points[1],
              "hypotheses": [{"generator": c.generator, "inlier_ratio": c.inlier_ratio,
                              "photometric_ncc": c.photometric_ncc} for c in tried],
              "mirror_inlier_ratio": None if mirror is None else mirror.inlier_ratio})


def _check_inputs(ref_img: np.ndarray, mov_img: np.ndarray, pyramid: PyramidConfig, reference_mask, moving_mask,
                  callback) -> None:
    """What :func:`register` takes besides its config, checked against the images (an :class:`InputError`
    for the first bad one)."""
    from .clouds import check_mask

    for img, name in ((ref_img, "the reference image"), (mov_img, "the moving image")):
        pyramid.check_shape(img.shape, name)
    check_mask(reference_mask, ref_img.shape, name="reference_mask")
    check_mask(moving_mask, mov_img.shape, name="moving_mask")
    check_callable(callback, "callback")


def _pyramids(ref_img: np.ndarray, mov_img: np.ndarray, reference_pyramid: ImagePyramid | None,
              moving_pyramid: ImagePyramid | None, *, levels: int, sampler: str, canny_percentile: float, seed: int,
              masks: tuple, max_points: tuple, given: tuple = (None, None)) -> tuple[CloudPyramid, CloudPyramid]:
    """The reference's and the moving image's cloud pyramids (seeds ``seed`` and ``seed + 1``), each level
    built when first used (a search that ends at level 1 never builds levels 2-3), drawn from the caller's
    :func:`~pcreg.registration.clouds.image_pyramid` where given. ``given``: the two images as the caller
    gave them, whose 16-bit values a refusal describes (:func:`~pcreg.frame.low_bits_note`)."""
    out = []
    for name, image, kept, mask, n, s in (("reference", ref_img, reference_pyramid, masks[0], max_points[0], seed),
                                          ("moving", mov_img, moving_pyramid, masks[1], max_points[1], seed + 1)):
        if kept is None:
            out.append(CloudPyramid.from_image(image, levels=levels, mask=mask, max_points=n, sampler=sampler,
                                               seed=s, canny_percentile=canny_percentile))
        else:
            kept = check_pyramid(image, kept, levels=levels, sampler=sampler, canny_percentile=canny_percentile,
                                 name=name)
            out.append(CloudPyramid.from_detections(image, kept, levels=levels, max_points=n, seed=s))
    for name, pyramid, image in zip(("reference", "moving"), out, given):
        if len(pyramid[0]) < 3:
            left_out = 1.0 - float(np.mean(pyramid.valid))
            why = low_bits_note(image) or (f"{100 * left_out:.0f}% of it is left out (pure black touching its border is "
                                           "read as padding from a warp, a transparent pixel as no picture), and the "
                                           f"rest holds none (pcreg.register's {name}_mask=None keeps every pixel)"
                                           if left_out >= 0.05 else None)
            raise RegistrationError(f"the {name} image has no usable edges" + (f": {why}" if why else " (a flat or empty image?)"))
    return out[0], out[1]


def _search(reference: CloudPyramid, moving: CloudPyramid, config: RegisterConfig, init, *,
            keep_iterations: bool) -> tuple[Candidate, list[Candidate], Candidate | None, Plausibility, GlobalSearch]:
    """:func:`register`'s search: the coarse-to-fine ICP, the plausibility test and the hypotheses' search, each
    built from its part of ``config`` on the two pyramids, then the candidates refined from ``init`` (a name or a
    3x3 start, :func:`_candidates`). Returns the best candidate, every one tried, the mirrored image's best (or
    None), the test, which judges the best, and the search (whose ORB matches and reference trees the checks
    share). ``keep_iterations``: each candidate keeps its ICP iterations (a callback reports the best's, instead of
    refining it a second time)."""
    icp, plausibility, s = config.icp, config.plausibility, config.search
    refiner = _refiner(reference, config, config.model, icp.backend, point_to_line=icp.refine == "point_to_line")
    test = Plausibility(reference, refiner.tree, model=config.model, min_inlier_ratio=plausibility.min_inlier_ratio,
                        inlier_tolerance=plausibility.inlier_tolerance,
                        reference_max_points=config.pyramid.reference_max_points)
    search = GlobalSearch(refiner, test.measure, model=config.model, generators=s.generators, angle_step=s.angle_step,
                          n_candidates=s.n_candidates, seed=s.seed, convincing=test.convincing,
                          keep_iterations=keep_iterations)
    tried, mirror = _candidates(init, moving, refiner, test, search)
    if not tried:
        raise search.nothing_refined()
    best = max(tried, key=lambda c: c.score)  # edges rank the hypotheses; intensities break repetitive ties
    return best, tried, mirror, test, search


def _candidates(init, moving: CloudPyramid, refiner: CoarseToFine, test: Plausibility,
                search: GlobalSearch) -> tuple[list[Candidate], Candidate | None]:
    """The refined hypotheses (the search's, or the one ``init`` names) and, where the search was not
    convinced, the best of the mirrored image's (None when not searched)."""
    if isinstance(init, str):  # one of the config's names, checked there
        if init in ("auto", "global"):
            tried = search.run(moving)
            convinced = any(search.is_convincing(c) and c.evidence.overlap >= MIRROR_OVERLAP for c in tried)
            if not test.worth_a_mirror(tried, convinced):
                return tried, None
            mirrored = search.run(moving.mirrored())
            return tried, (max(mirrored, key=lambda c: c.score) if mirrored else None)
        ref_shape = refiner.reference.image.shape
        init = (about_point(np.eye(3), image_center(moving.image.shape), image_center(ref_shape))
                if init == "center" else np.eye(3))
        refined, iterations = search.refine(moving, init)
        return [Candidate(Hypothesis("init", init), refined, test.measure(moving, refined.matrix),
                          iterations=iterations)], None
    # a start given as a matrix: refined as the search's own starts are (again from full resolution where the
    # coarse levels leave it unconvincing, the better kept), so a start at the answer is not pulled off it
    gray = gray_level(moving.image, search.p_level, valid=moving.valid)
    return [search.evaluate(Hypothesis("init", init), moving, gray, again=True)], None

