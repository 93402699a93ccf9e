"""Run both ICP backends on identical inputs and report where they differ.

Identical inputs: the same clouds (extracted or downsampled once), the same initial guess, the same
correspondence distances, iteration limits and stopping rule (Open3D's, ``relative_fitness`` and
``relative_rmse`` compared as absolute changes). The reference backend runs with exact KD-tree
correspondences, point-to-point, no robust weights — the configuration that must reproduce Open3D.
How the results are compared (tolerances, disagreements, one row of the report): :mod:`.compare`.
"""

from __future__ import annotations

import os
import sys
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..cloud_reader import CLOUD_SUFFIXES, load_cloud
from ..errors import InputError, RegistrationError, _one_line
from ..formats import IMAGE_SUFFIXES
from ..frame import MIN_SIDE
from ..registration.clouds import as_rgb_uint8, load_image_and_mask
from ..registration.api import check_cloud, register
from ..registration.config import RegisterConfig
from ..registration.icp_options import ICPOptions
from ..registration.result import IcpIteration, RegistrationResult
from ..registration.transforms import apply, corners, rotation_disagreement_deg
from .base import unconstrained as unconstrained  # re-exported: the test that marks the cross-check's rows
from .compare import (  # re-exported: the comparison of the rows, imported from here by the suite, tools and tests
    FIXED_POINT_TOLERANCE as FIXED_POINT_TOLERANCE,
    OBJECTIVE_ROTATION_DEG as OBJECTIVE_ROTATION_DEG,
    OBJECTIVE_SCALE as OBJECTIVE_SCALE,
    OBJECTIVE_TRANSLATION as OBJECTIVE_TRANSLATION,
    REFERENCE as REFERENCE,
    STEP_TOLERANCE as STEP_TOLERANCE,
    CloudCrosscheck as CloudCrosscheck,
    implementation_row,
    relative_difference,
    compare_matrices as compare_matrices,
    step_tolerance as step_tolerance,
    trace_divergence as trace_divergence,
)


#: The registration both backends run in a cross-check of two images: 30 ICP iterations a level and
#: Open3D's default stopping thresholds (1e-6), more moving points than ``register``'s default, no
#: point-to-line finish (only the reference backend has it) and no plausibility test (a cross-check
#: reports, it does not refuse).
CROSSCHECK_REGISTRATION = RegisterConfig.of(iterations=30, relative_fitness=1e-6, relative_rmse=1e-6,
                                            max_points=(3000, 1500, 800, 400), refine="none", min_inlier_ratio=None)


@dataclass(frozen=True)
class CrosscheckConfig:
    """Settings of a cross-check: the registration of images (:data:`CROSSCHECK_REGISTRATION`; its
    backend is set per run), whose iteration limit and stopping thresholds are also the defaults of a
    cloud cross-check."""

    registration: RegisterConfig = CROSSCHECK_REGISTRATION


@dataclass(frozen=True)
class CrosscheckReport:
    kind: str  # "images" or "clouds"
    reference: RegistrationResult
    open3d: RegistrationResult
    config: CrosscheckConfig
    max_corner_disagreement_px: float | None = None
    rotation_disagreement_deg: float | None = None
    translation_disagreement: float | None = None
    matrix_relative_disagreement: float = 0.0
    extra: dict = field(default_factory=dict)
    refused: str | None = None  # why pcreg.register refuses the pair: neither pose is trusted

    def to_dict(self) -> dict:
        out = {"kind": self.kind, "reference": self.reference.to_dict(), "open3d": self.open3d.to_dict(),
               "refused": self.refused, "matrix_relative_disagreement": self.matrix_relative_disagreement,
               "reference_seconds": self.reference.seconds, "open3d_seconds": self.open3d.seconds}
        if self.kind == "images":
            out["max_corner_disagreement_px"] = self.max_corner_disagreement_px
        out["rotation_disagreement_deg"] = self.rotation_disagreement_deg
        out["translation_disagreement"] = self.translation_disagreement
        out["config"] = asdict(self.config)
        out.update(self.extra)
        return out


def crosscheck_images(reference_image: np.ndarray, moving_image: np.ndarray, *,
                      config: CrosscheckConfig = CrosscheckConfig(),
                      callback: Callable[[IcpIteration], None] | None = None,
                      reference_mask: np.ndarray | str | None = "auto",
                      moving_mask: np.ndarray | str | None = "auto") -> CrosscheckReport:
    """:func:`pcreg.register`, the function users call, once with each backend and the same options (the masks
    as it takes them: an image file's transparent pixels left out, :func:`~pcreg.registration.clouds.load_image_and_mask`).

    Both runs build the same clouds (same seeds), search the same hypotheses and refine each with their
    own ICP at every step, and the point-to-line finish, which only the reference backend has, is not used.
    Open3D is run one iteration at a time so that both iteration counts are exact. A cross-check reports, it
    does not refuse: where the plausibility test (on for the reference's run, with its default threshold)
    refuses the pair (unrelated images, a mirror image), both poses are still compared, and the report's
    ``refused`` says why neither is trusted.
    """
    from ..registration.api import register_judged
    from ..registration.config import DEFAULT_MIN_INLIER_RATIO

    ref = as_rgb_uint8(reference_image, name="reference image")
    mov = as_rgb_uint8(moving_image, name="moving image")
    results = {}
    untested = config.registration.replace(model_check=False)
    report = callback or (lambda it: None)  # a callback makes both backends report every iteration (Open3D then
    # runs stepwise: exact counts). One search: the test judges its pose, which is kept where it is refused.
    results["reference"], refusal = register_judged(ref, mov, config=untested.replace(min_inlier_ratio=DEFAULT_MIN_INLIER_RATIO),
                                                    backend="reference", callback=report, reference_mask=reference_mask,
                                                    moving_mask=moving_mask)
    refused = None if refusal is None else str(refusal).removeprefix("registration refused: ")
    results["open3d"] = register(ref, mov, config=untested, backend="open3d", callback=report,
                                 reference_mask=reference_mask, moving_mask=moving_mask)
    a, b = results["reference"], results["open3d"]
    c = corners(mov.shape)
    return CrosscheckReport(
        kind="images", reference=a, open3d=b, config=config,
        max_corner_disagreement_px=float(np.max(np.linalg.norm(apply(a.matrix, c) - apply(b.matrix, c), axis=1))),
        rotation_disagreement_deg=rotation_disagreement_deg(a.matrix, b.matrix),
        translation_disagreement=float(np.linalg.norm(a.matrix[:2, 2] - b.matrix[:2, 2])),
        matrix_relative_disagreement=relative_difference(a.matrix, b.matrix),
        extra={"generators": [a.generator, b.generator],
               "inlier_ratios": [a.inlier_ratio, b.inlier_ratio]}, refused=refused)



def suffixless(error: InputError) -> InputError:
    """The refusal of a file without a suffix read as an image (``error``): a point cloud is read by its suffix."""
    return InputError(f"{error} (a file without a suffix is read as an image; a point cloud is read by its suffix: "
                      f"{', '.join(CLOUD_SUFFIXES)})")

def crosscheck(reference, moving, *, config: CrosscheckConfig = CrosscheckConfig(), callback=None,
               implementations: Sequence[str] | None = None, **cloud_options):
    """Cross-check the backends: register ``moving`` onto ``reference`` (two images or two point clouds,
    arrays or file paths); for clouds the reference is the ICP target and the moving cloud the source.

    Images: both backends through the image pipeline, a :class:`CrosscheckReport` (``callback`` told each
    backend's every iteration, :class:`~pcreg.registration.result.IcpIteration`). Clouds: every name in
    ``implementations`` (default reference and open3d) through :func:`crosscheck_implementations` with
    ``cloud_options`` (its keyword arguments; ``options`` defaults to the registration's iterations and
    thresholds), a
    :class:`CloudCrosscheck`.

    Image arrays are (H, W, 3)/(H, W); cloud arrays (N, 2|3), of any numeric type (an (H, W) array 2 or 3 wide
    is a cloud). Paths are read by suffix: images through
    OpenCV, clouds by :func:`pcreg.cloud_reader.load_cloud` (.ply/binary .pcd/.xyz through Open3D, .npy through
    numpy, ASCII .pcd, .pts and .txt/.csv by pcreg).
    """
    def kind_of(x, name):
        if isinstance(x, (str, os.PathLike)):
            suffix = Path(x).suffix.lower()
            if suffix in CLOUD_SUFFIXES:
                return "clouds", load_cloud(x)
            if suffix in IMAGE_SUFFIXES:  # its transparent pixels left out, as pcreg register does
                return "images", load_image_and_mask(x)
            if not suffix:
                try:
                    return "images", load_image_and_mask(x)
                except InputError as error:
                    raise suffixless(error) from None
            raise InputError(f"{x}: unknown file type {suffix!r} (an image or a point cloud)")
        if type(x).__module__.startswith("open3d") and hasattr(x, "points"):  # as pcreg.icp says it
            raise InputError(f"{name}: an Open3D {type(x).__name__}, not an array; pass np.asarray(cloud.points)")
        arr = np.asarray(x)
        if arr.ndim == 2 and arr.shape[1] in (2, 3):  # an image two or three pixels wide is no image to register
            return "clouds", arr
        if arr.ndim == 2 and 0 < arr.shape[1] < MIN_SIDE:  # (N, 4) x, y, z, intensity: no image either (too narrow)
            raise InputError(f"{name}: expected an (N, 2) or (N, 3) array of points (or an image at least {MIN_SIDE} "
                             f"px wide), got shape {arr.shape}")
        return "images", (arr, "auto")

    from ..validation import short_repr

    if not isinstance(config, CrosscheckConfig):
        raise InputError(f"config must be a CrosscheckConfig, got {type(config).__name__}")
    if callback is not None and not callable(callback):
        raise InputError(f"callback must be callable or None, got {type(callback).__name__}")
    if implementations is not None:
        if isinstance(implementations, str):
            implementations = (implementations,)
        if not isinstance(implementations, (tuple, list)) or not all(isinstance(n, str) for n in implementations):
            raise InputError(f"implementations must be a sequence of names, got {short_repr(implementations)}")
    ka, A = kind_of(reference, "reference")
    kb, B = kind_of(moving, "moving")
    named = [str(x) if isinstance(x, (str, os.PathLike)) else n for x, n in ((moving, "moving"), (reference, "reference"))]
    if ka != kb:  # named as given: files or roles
        raise InputError(f"{named[0]}: {'an image' if kb == 'images' else 'a cloud'}, and {named[1]} "
                         f"{'an image' if ka == 'images' else 'a cloud'}: give two images or two clouds")
    if ka == "clouds":
        if callback is not None:  # refused, not ignored: no implementation of the registry calls one
            raise InputError("callback: a cross-check of clouds calls none (each implementation runs in its own way); "
                             "for one's iterations use pcreg.icp(source, target, callback=...), or give two images")
        if np.ndim(A) == np.ndim(B) == 2 and np.shape(A)[1] != np.shape(B)[1]:
            raise InputError(f"{named[0]}: a {np.shape(B)[1]}-D cloud, and {named[1]} is {np.shape(A)[1]}-D (the two "
                             "clouds need the same dimension)")
        icp = config.registration.icp
        cloud_options.setdefault("options", ICPOptions(max_iteration=icp.iterations, relative_fitness=icp.relative_fitness,
                                                       relative_rmse=icp.relative_rmse))
        cloud_options.setdefault("files", tuple(str(x) if isinstance(x, (str, os.PathLike)) else None for x in (moving, reference)))
        return crosscheck_implementations(B, A, implementations=tuple(implementations or ("reference", "open3d")),
                                          **cloud_options)
    (A, mask_a), (B, mask_b) = A, B
    return crosscheck_images(A, B, config=config, callback=callback, reference_mask=mask_a, moving_mask=mask_b)


# ---------------------------------------------------------------------------------------------------
# Clouds: every implementation of the registry on the same pinned inputs
# ---------------------------------------------------------------------------------------------------

def default_max_distance(target: np.ndarray, *, name: str = "target") -> float:
    """1% of the target's bounding-box diagonal: a scan pair taken a step apart is misaligned by about
    that much, and a gate this tight keeps points without a counterpart out of the fit (an :class:`InputError`
    beginning with ``name`` when the target has no extent)."""
    diag = float(np.linalg.norm(target.max(axis=0) - target.min(axis=0)))
    if not diag > 0:
        raise InputError(f"{name}: {'a single point' if len(target) == 1 else f'its {len(target)} points coincide'}: no "
                         "correspondence distance can be derived from its extent (give max_correspondence_distance, "
                         "--max-distance)")
    return diag / 100.0


def converged_settings(pinned, extent: float | None = None):
    """The reference's settings "to convergence": at least 200 iterations and thresholds that only an
    unchanged correspondence set meets (then the closed form returns the same pose exactly): 1e-12 on the
    fitness, and on the inlier RMSE 1e-12 of the correspondence distance (an absolute 1e-12 was met before the
    pairs settled on clouds given in small units: 128 iterations of 137 on clouds 2.4e-5 across), or of the
    target's ``extent`` (its bounding-box diagonal) where that is smaller: a gate of 1e9 on clouds a unit across
    ("every pair") made it 1e-3, and the run stopped 9 iterations in at RMSE 0.024, short of the 1.7e-15 its
    pinned row reached, and a row that reached it was said to fit better than ICP's best."""
    scale = float(pinned.max_correspondence_distance)
    if extent is not None and 0.0 < extent < scale:
        scale = float(extent)
    return pinned.replace(max_iterations=max(int(pinned.max_iterations), 200), relative_fitness=1e-12,
                          relative_rmse=1e-12 * scale)


def check_truth(truth, d: int, name: str = "truth") -> np.ndarray:
    """A ground truth ``T_target_source`` of ``d``-D clouds: a finite rigid (d+1)x(d+1) transform
    (:func:`~pcreg.validation.check_matrix`, :func:`~pcreg.registration.transforms.rigid_problem`), or an
    :class:`InputError` beginning with ``name``."""
    from ..registration.transforms import rigid_problem
    from ..validation import check_matrix

    T = check_matrix(truth, name, d + 1)
    problem = rigid_problem(T)
    if problem is not None:
        raise InputError(f"{name}: {problem}")
    return T


def crosscheck_implementations(source: np.ndarray, target: np.ndarray, *, implementations: Sequence[str] = ("reference", "open3d"),
                               options: ICPOptions = ICPOptions(), init: np.ndarray | None = None,
                               voxel_size: float | None = None, truth: np.ndarray | None = None,
                               timeout: float | None = None, progress: bool = False,
                               on_result: Callable[[str, object], None] | None = None,
                               files: tuple[str | None, str | None] = (None, None)) -> CloudCrosscheck:
    """Run each implementation (names, ``py:`` or ``cmd:`` specs) on the same pinned inputs and compare it
    with pcreg's reference ICP.

    source, target : (N, d), (M, d), d = 2 or 3; ``target`` is fixed, the result maps ``source`` onto it.
    options : the pinned correspondence distance (None: :func:`default_max_distance` of the target) and
        stopping rule (``max_iteration``, ``relative_fitness``, ``relative_rmse``) of an
        :class:`~pcreg.registration.icp_options.ICPOptions`; the rest is pinned (rigid, point to point,
        one scale) and must keep its default.
    voxel_size : both clouds are voxel-downsampled once (:func:`pcreg.registration.api.voxel_downsample`)
        before any implementation sees them.
    truth : optional (d+1, d+1) ground truth; rows then also report their error against it.
    on_result : called with (name, RegistrationResult or exception) as each implementation finishes.
    files : the files ``source`` and ``target`` were read from (None: given as an array), which the messages
        about them name (:func:`crosscheck` of two files gives them).

    A failing or missing implementation becomes its row's one-line ``error``; the others still run.
    """
    from .. import implementations as impls

    _check_pinned_options(options)
    files = _check_files(files)
    max_iterations, relative_fitness = options.max_iteration, options.relative_fitness
    src, tgt, T0, max_correspondence_distance = _pinned_clouds(source, target, init=init, voxel_size=voxel_size,
                                                               max_correspondence_distance=options.max_correspondence_distance,
                                                               max_iterations=max_iterations, files=files)
    relative_rmse = options.stopping_rmse(src, tgt)
    d = src.shape[1]
    truth = None if truth is None else check_truth(truth, d)
    names = list(dict.fromkeys([REFERENCE, *implementations]))
    adapters, errors = _adapters(names, timeout)
    pinned = impls.Pinned(src, tgt, T0, float(max_correspondence_distance), int(max_iterations),
                          float(relative_fitness), float(relative_rmse))
    diag = float(np.linalg.norm(tgt.max(axis=0) - tgt.min(axis=0)))
    # every implementation's run marks its pose with it too; the rows name the clouds' files
    problem = pinned.undetermined and unconstrained(src, tgt, (files[0] or "source", files[1] or "target"))
    _check_enough_correspondences(src, tgt, T0, float(max_correspondence_distance), files)  # anything to run on?
    outcomes = _run_each(names, adapters, errors, pinned, progress=progress, on_result=on_result)
    ref = outcomes.get(REFERENCE)
    conv, conv_info = _reference_at_convergence(adapters, outcomes, pinned, diag)
    rows, traces = {}, {}
    for name in names:
        o = outcomes.get(name)
        rows[name] = implementation_row(name, o, adapters.get(name), errors, pinned, ref=ref, conv=conv, src=src,
                                        diag=diag, truth=truth, problem=problem)
        if isinstance(o, RegistrationResult):
            traces[name] = o.trace
    settings = {**pinned.params(), "init": T0.tolist(), "voxel_size": voxel_size, "dimension": d,
                "source_points": len(src), "target_points": len(tgt), "target_diagonal": diag,
                "unconstrained": problem}
    if ref is None:
        settings["reference_error"] = errors.get(REFERENCE)
    return CloudCrosscheck(rows=rows, settings=settings, reference_at_convergence=conv_info, traces=traces,
                           source=src, target=tgt)


def _check_pinned_options(options: ICPOptions) -> None:
    """:class:`InputError` unless ``options`` sets only what the cross-check lets vary (the correspondence
    distance and the stopping rule): every implementation runs the rigid point-to-point ICP at one scale."""
    if not isinstance(options, ICPOptions):
        raise InputError(f"options must be a pcreg.ICPOptions, got {type(options).__name__}")
    pinned = ("max_correspondence_distance", "max_iteration", "relative_fitness", "relative_rmse")
    changed = [f.name for f in fields(ICPOptions) if f.name not in pinned and getattr(options, f.name) != f.default]
    if changed:
        raise InputError(f"the cross-check pins the rigid point-to-point ICP at one scale; options may set "
                         f"{', '.join(pinned)} only, not {', '.join(changed)}")


def _check_files(files) -> tuple[str | None, str | None]:
    """``crosscheck_implementations``' ``files``: two file names (or None each), else an :class:`InputError`."""
    from ..validation import short_repr

    if not (isinstance(files, (tuple, list)) and len(files) == 2
            and all(f is None or isinstance(f, (str, os.PathLike)) for f in files)):
        raise InputError(f"files must be two file names (or None each), got {short_repr(files)}")
    return (None if files[0] is None else str(files[0]), None if files[1] is None else str(files[1]))


def _pinned_clouds(source, target, *, init, voxel_size, max_correspondence_distance, max_iterations,
                   files: tuple = (None, None)):
    """The checked (and voxel-downsampled) clouds, the initial pose and the correspondence distance
    every implementation gets; a bad cloud's message names its file where ``files`` gives it."""
    from ..registration.api import voxel_downsample
    from ..registration.transforms import nearest_rigid, rigid_problem
    from ..validation import check_float, check_int, check_matrix

    src = check_cloud(source, files[0] or "source")
    tgt = check_cloud(target, files[1] or "target")
    if src.shape[1] != tgt.shape[1]:
        raise InputError(f"source is {src.shape[1]}-D but target is {tgt.shape[1]}-D")
    d = src.shape[1]
    if voxel_size is not None and voxel_size is not False and voxel_size != 0:
        voxel_size = check_float(voxel_size, "voxel_size", lo=0, lo_open=True)
        kept = voxel_downsample(src, voxel_size), voxel_downsample(tgt, voxel_size)
        for cloud, left, name in zip((src, tgt), kept, (files[0] or "source", files[1] or "target")):
            if len(left) < 3 <= len(cloud):  # the message would blame the file for the points the voxels merged
                raise InputError(f"{name}: voxel_size {voxel_size:g} (--voxel-size) merges its {len(cloud)} points "
                                 f"into {len(left)}, and the ICP needs 3; give a smaller voxel size")
        src, tgt = kept
    # the shared inputs are checked here, once, as the reference checks them: a bad one is the
    # caller's, not a failure of each implementation in turn
    T0 = np.eye(d + 1) if init is None else check_matrix(init, "init", d + 1)
    problem = rigid_problem(T0)
    if problem is not None:
        raise InputError(f"init: {problem}, and the cross-check pins the rigid ICP")
    T0 = nearest_rigid(T0)  # every implementation starts from, and so returns, a rigid matrix
    if max_iterations == 0:  # ICPOptions takes 0 (the initial pose) and checked it is an integer
        raise InputError("options.max_iteration must be 1 or more in a cross-check: with 0 every implementation "
                         "returns the initial pose, and there is nothing to compare")
    max_iterations = check_int(max_iterations, "options.max_iteration", lo=1, hi=100_000)
    if max_correspondence_distance is None:
        max_correspondence_distance = default_max_distance(tgt, name=files[1] or "target")
    if not max_correspondence_distance > 0:
        raise InputError("max_correspondence_distance must be > 0")
    return src, tgt, T0, max_correspondence_distance


def _check_enough_correspondences(src: np.ndarray, tgt: np.ndarray, T0: np.ndarray, distance: float,
                                  files: tuple = (None, None)) -> None:
    """A :class:`RegistrationError` when fewer source points, at the initial pose, have a target point within
    ``distance`` than a rigid motion needs (2 in 2-D, 3 in 3-D). With none, every ICP stops where it started
    (fitness 0), and a cross-check of identities would read as implementations that agree and converged;
    with one or two in 3-D the rotation is not determined: pcreg's reference stops where it started, others
    (Open3D's step takes any non-empty set) move by a rotation the pairs do not determine; a source of fewer
    points than that is refused as such (no init or distance helps). The message names
    the ``files`` the clouds were read from, where given ("S.ply onto T.ply: ...")."""
    from scipy.spatial import cKDTree

    from ..registration.reference import pairs_needed

    d = src.shape[1]
    need = pairs_needed("rigid", d)
    if len(src) < need:  # no init or distance makes them enough: the file, not the pose, is short
        raise RegistrationError(f"registration refused: {files[0] or 'source'}: {len(src)} point(s) are too few for a "
                                f"rigid motion in {d}-D (it needs {need})")
    moved = src @ T0[:-1, :-1].T + T0[:-1, -1]
    near, _ = cKDTree(tgt).query(moved, k=1, distance_upper_bound=distance)
    found = int(np.count_nonzero(np.isfinite(near)))
    pair = "" if files == (None, None) else f"{files[0] or 'the source'} onto {files[1] or 'the target'}: "
    started = "give --init" if np.array_equal(T0, np.eye(d + 1)) else "another --init"  # one was given: not "give"
    if found == 0:
        raise RegistrationError(f"registration refused: {pair}no source point lies within the correspondence distance "
                                f"{distance:g} of a target point at the initial pose; every ICP would stop where it "
                                f"started ({started}, or a larger --max-distance)")
    if found < need:
        raise RegistrationError(f"registration refused: {pair}{found} source point{'s' if found > 1 else ''} of "
                                f"{len(src)} lie{'' if found > 1 else 's'} within the correspondence distance "
                                f"{distance:g} of a target point at the initial pose, and a rigid motion in {d}-D "
                                f"needs {need}: the pairs do not determine the rotation ({started}, or a larger "
                                "--max-distance)")


def check_implementations(implementations: Sequence[str], *, timeout: float | None = None) -> None:
    """An :class:`InputError` when a name of ``implementations`` is no implementation: an unknown built-in name, or a
    ``py:`` module or function, or a ``cmd:`` program, that does not exist (as :func:`crosscheck_implementations`
    finds before it runs any); a module that fails in its own import is its row, not bad input. A suite checks its
    names once, before its first case (each case's one row blamed the reference for a misspelt name, exit 0)."""
    _adapters(list(dict.fromkeys([REFERENCE, *implementations])), timeout)


def _adapters(names: list[str], timeout: float | None) -> tuple[dict, dict]:
    """{name: adapter} and {name: one-line error} for the user implementations that cannot be loaded
    (an unknown built-in name, the reference, or a ``py:`` module, function or ``cmd:`` program that does
    not exist, is an :class:`InputError`)."""
    from .. import implementations as impls

    adapters, errors = {}, {}
    for name in names:
        try:
            adapter = adapters[name] = impls.get(name, timeout=timeout)
            if isinstance(adapter, impls.PythonCallable):  # imported before any runs: no such function
                adapter.load()                             # is bad input, not a row
        except impls.ImplementationError as exc:
            adapters.pop(name, None)
            if name == REFERENCE or not (name.startswith("py:") or name.startswith("cmd:")):
                raise InputError(_one_line(exc)) from None
            errors[name] = _one_line(exc)
    return adapters, errors


def _run_each(names: list[str], adapters: dict, errors: dict, pinned, *, progress: bool, on_result) -> dict:
    """{name: RegistrationResult, or "missing" for a library not installed}; each failure's one line goes to ``errors``."""
    from .. import implementations as impls

    outcomes: dict = {}
    it = names
    if progress:
        from tqdm import tqdm

        it = tqdm(names, desc="implementations", unit="impl", file=sys.stderr, leave=False)
    for name in it:
        if name in errors:
            continue
        outcome, said = impls.run_quietly(adapters[name], pinned)  # a failure is that implementation's alone
        if isinstance(outcome, Exception):
            errors[name] = _one_line(outcome)
            if isinstance(outcome, impls.MissingLibrary):
                outcomes[name] = "missing"
        else:  # what its library printed or warned goes into its row, not onto the terminal
            outcomes[name] = replace(outcome, info={**outcome.info, "said": said}) if said else outcome
        if on_result is not None:
            on_result(name, outcomes.get(name, errors.get(name)))
    return outcomes


def _reference_at_convergence(adapters: dict, outcomes: dict, pinned, extent: float | None = None) -> tuple:
    """The reference run to convergence and its summary, when an implementation compares at the fixed
    point or by objective (else (None, None)); ``extent``: the target's bounding-box diagonal
    (:func:`converged_settings`)."""
    if outcomes.get(REFERENCE) is None or not any(
            isinstance(outcomes.get(n), RegistrationResult) and adapters[n].comparability != "step"
            for n in outcomes if n != REFERENCE):
        return None, None
    try:
        conv = adapters[REFERENCE].run(converged_settings(pinned, extent))
    except Exception as exc:  # noqa: BLE001
        return None, {"error": _one_line(exc)}
    return conv, {"matrix": conv.matrix.tolist(), "iterations": conv.iterations, "converged": conv.converged,
                  "fitness": conv.fitness, "inlier_rmse": conv.inlier_rmse,
                  "settings": converged_settings(pinned, extent).params()}
