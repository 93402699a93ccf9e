"""Thesis Ch. 5: classify rotated frames before and after registering them back.

For sampled frames of each dataset, naive Bayes (RGB + HSV + row) is trained on the original frame; the
frame is rotated about its centre by each angle (default 0, 5, ..., 180 degrees) onto a canvas large
enough to hold all of it (``--canvas loose``, as MATLAB's ``imrotate`` does by default; ``crop`` keeps
the original size and loses the corners), then

- ``before``: the rotated frame, centred on the original's grid without registration, is classified
  and scored against the original labels (the thesis's "before");
- ``after``: the rotated frame is registered back to the original (``init="auto"``: a global rotation
  search, then ICP; rigid model), warped onto the original's grid and classified, black border
  included, and scored against the original labels;
- ``after_masked``: as ``after``, with the pixels that the warped image does not cover (outside the
  rotated frame's content) classified from the unregistered frame;
- ``after_cropped``: as ``after``, scored only where the warped image has content.

Each (dataset, sampled frame, backend) is one unit of work (``--workers``); finished units are kept in
``OUT/units/`` and skipped when the same command is run again. Outputs: results.json, config.json,
rotation_<backend>.csv/.md, checks.md and rotation.png (curves like the thesis's Figures 5.1-5.6).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, replace
from typing import ClassVar
from pathlib import Path

from ..classification.features import DEFAULT_FEATURES
from .results import Results
from ..registration.config import RegisterConfig
from ..recording.interface import RecorderProtocol
from ..recording.null import NULL_RECORDER


DEFAULT_ANGLES = tuple(float(a) for a in range(0, 181, 5))
KEYS = ("before", "after", "after_masked", "after_cropped")


@dataclass(frozen=True)
class RotationConfig:
    """Everything that determines ``pcreg evaluate rotation``'s numbers (written as config.json).

    angles : degrees. samples : frames per dataset, evenly spaced (first, ..., last).
    canvas : ``loose`` (holds the whole rotated frame) or ``crop`` (original size).
    backends, data, frames, size, seed : as in ``pcreg evaluate sequence``.
    registration : :func:`pcreg.register`'s options (its backend is set per unit from ``backends``).
    features : the classifier's features.
    """

    report: ClassVar[str] = "rotation"  #: its report's name (:data:`~.reports.files.REPORT_NAMES`)

    data: str = "synthetic"
    angles: tuple[float, ...] = DEFAULT_ANGLES
    samples: int = 3
    canvas: str = "loose"
    backends: tuple[str, ...] = ("reference",)
    frames: int | None = None
    size: tuple[int, int] | None = None
    seed: int = 0
    registration: RegisterConfig = RegisterConfig()
    features: tuple[str, ...] = DEFAULT_FEATURES



# ---------------------------------------------------------------------------------------------
# one frame
# ---------------------------------------------------------------------------------------------

def rotate_frame(image, labels, angle: float, *, canvas: str = "loose"):
    """Rotate a frame about its centre.

    image : (H, W, 3) uint8; labels : (H, W) uint8. Returns ``(image_r, labels_r, content, T_rot)``:
    the rotated image and labels (unknown = 2 outside the frame) on the canvas, ``content`` (H', W')
    bool where the rotated frame has data, and ``T_rot`` (3, 3) original -> canvas pixel coordinates.
    """
    import math

    from ..registration.warp import warp
    from ..registration.transforms import about_point, image_center, rigid2d

    h, w = image.shape[:2]
    if canvas == "loose":
        a = math.radians(angle)
        cw = int(math.ceil(abs(w * math.cos(a)) + abs(h * math.sin(a)) - 1e-6))
        ch = int(math.ceil(abs(w * math.sin(a)) + abs(h * math.cos(a)) - 1e-6))
        shape = (max(ch, 8), max(cw, 8))
    else:
        shape = (h, w)
    T_rot = about_point(rigid2d(angle), image_center((h, w)), image_center(shape))
    image_r, content = warp(image, T_rot, shape=shape)
    labels_r, _ = warp(labels, T_rot, shape=shape, interpolation="nearest", fill=2)
    return image_r, labels_r, content, T_rot


def run_unit(unit, *, recorder=NULL_RECORDER, frame_counter: list[int] | None = None) -> dict:
    """Every angle for one sampled frame with one backend: a pure function of ``unit``. With a
    recorder, each angle is logged at the next index of the ``frame`` timeline (``frame_counter[0]``), and
    the result's ``recording_frames`` maps each angle to that index. An :class:`~pcreg.errors.InputError` (a frame
    too small to register, labels of one class) names the dataset and frame."""
    from ..errors import InputError
    from .units import load_cached

    try:
        return _run_unit(unit, recorder=recorder, frame_counter=frame_counter)
    except InputError as exc:
        cfg = unit.config
        frame = load_cached(cfg.data, frames=cfg.frames, size=cfg.size, seed=cfg.seed)[unit.dataset][unit.index]
        raise InputError(f"dataset {unit.dataset}, frame {frame.name}: {exc}") from None


def _run_unit(unit, *, recorder=NULL_RECORDER, frame_counter: list[int] | None = None) -> dict:
    import numpy as np

    from ..registration.api import register
    from ..registration.warp import warp
    from ..errors import RegistrationError
    from ..classification.metrics import error_rate
    from ..classification.bayes import fit_classifier
    from ..registration.transforms import about_point, image_center, max_corner_error
    from .units import angle_key, load_cached

    cfg = unit.config
    t0 = time.perf_counter()
    frame = load_cached(cfg.data, frames=cfg.frames, size=cfg.size, seed=cfg.seed)[unit.dataset][unit.index]
    clf = fit_classifier([frame], features=cfg.features)
    shape = frame.shape
    out = {"dataset": unit.dataset, "index": unit.index, "name": frame.name, "backend": unit.backend, "angles": {}}
    recorded: dict[str, int] = {}
    on_angle = _angle_logger(recorder, unit, frame_counter if frame_counter is not None else [0], recorded)
    for angle in cfg.angles:
        image_r, labels_r, content, T_rot = rotate_frame(frame.image, frame.labels, angle, canvas=cfg.canvas)
        T_centre = about_point(np.eye(3), image_center(image_r.shape), image_center(shape))
        unreg, _ = warp(image_r, T_centre, shape=shape)
        pred_before = clf.predict(unreg)
        row = {"before": error_rate(pred_before, frame.labels)}
        t_reg = time.perf_counter()
        try:
            res = register(frame.image, image_r, config=cfg.registration.replace(model_check=False), backend=unit.backend,
                           callback=recorder.icp_callback(unit.backend))
            T, reason = res.matrix, None
        except RegistrationError as exc:
            res, T, reason = None, None, str(exc)
        row["seconds_register"] = time.perf_counter() - t_reg
        if T is not None:
            warped, inside = warp(image_r, T, shape=shape)
            has, _ = warp(content.astype(np.uint8), T, shape=shape, interpolation="nearest")
            valid = inside & has.astype(bool)
            pred_after = clf.predict(warped)
            row["after"] = error_rate(pred_after, frame.labels)
            pred_masked = np.where(valid, pred_after, pred_before)
            row["after_masked"] = error_rate(pred_masked, frame.labels)
            row["after_cropped"] = error_rate(pred_after, frame.labels, mask=valid)
            row["corner_error"] = max_corner_error(T @ T_rot, np.eye(3), shape)
            row["valid_fraction"] = float(valid.mean())
            row["fitness"] = float(res.fitness)
        else:  # no transform: a system would go on with the unregistered frame
            warped, valid, pred_after, pred_masked = unreg, np.ones(shape, bool), pred_before, pred_before
            row.update(after=row["before"], after_masked=row["before"], after_cropped=row["before"],
                       corner_error=None, valid_fraction=0.0, fitness=0.0)
        row["registered"] = T is not None
        row["reason"] = reason
        out["angles"][angle_key(angle)] = row
        if on_angle is not None:
            on_angle(angle, row, images=(frame.image, image_r, warped, valid), T=T, reason=reason,
                     labels=(frame.labels, pred_after, pred_masked, pred_before))
    if recorded:
        out["recording_frames"] = recorded
    out["seconds"] = time.perf_counter() - t0
    return out


def _angle_logger(rec: RecorderProtocol, unit, counter: list[int], recorded: dict[str, int]):
    """The hook that logs one angle at the next index of the ``frame`` timeline; None when not recording."""
    if not rec.enabled:
        return None
    from .units import angle_key

    prefix = f"{unit.dataset}/frame{unit.index}/{unit.backend}"

    def on_angle(angle, row, *, images, T, reason, labels) -> None:
        reference, rotated, warped, valid = images
        truth, after, after_masked, before = labels
        rec.set_frame(counter[0])
        recorded[angle_key(angle)] = counter[0]
        counter[0] += 1
        rec.log_text(f"{prefix}: rotated by {angle:g} degrees")
        rec.log_images(reference=reference, moving=rotated, warped=warped, valid_mask=valid)
        if T is not None:
            rec.log_transform(T)
        else:
            rec.log_failure(f"{prefix} at {angle:g} degrees: {reason}")
        rec.log_labels(truth=truth)
        rec.log_labels(predicted=after, prefix="after")
        rec.log_labels(predicted=after_masked, prefix="after_masked")
        rec.log_labels(predicted=before, prefix="before")
        rec.log_errors({f"{prefix}/{k}": row[k] for k in KEYS})

    return on_angle


# ---------------------------------------------------------------------------------------------
# the evaluation
# ---------------------------------------------------------------------------------------------

def sample_indices(n: int, samples: int) -> list[int]:
    """``samples`` frame indices evenly spaced over 0..n-1 (fewer for a short sequence)."""
    import numpy as np

    if n <= 0:
        return []
    return sorted({int(round(v)) for v in np.linspace(0, n - 1, min(samples, n))})


def check_angles(angles) -> None:
    """Refuse two angles that the results name alike (:func:`~pcreg.experiments.units.angle_key`, 6 significant
    digits): one row would hold the second's errors under both."""
    from ..errors import InputError
    from .units import angle_key

    seen: dict[str, float] = {}
    for a in angles:
        key = angle_key(a)
        if key in seen:
            raise InputError(f"--angles: {seen[key]!r} and {a!r} are one angle in the results, which name each by 6 "
                             f"significant digits ({key}); give each angle once")
        seen[key] = a


def kept(unit, result: dict) -> bool:
    """Whether a kept unit holds a row of every angle of the run (else it is run again)."""
    from .units import angle_key, holds

    return (holds(result, unit, ("angles", "name"), same=("dataset", "index", "backend"))
            and isinstance(result["angles"], dict) and all(angle_key(a) in result["angles"] for a in unit.config.angles))


def evaluate(config: RotationConfig, *, out: str | Path | None = None, force: bool = False, executor=None,
             recorder=NULL_RECORDER, show_progress: bool | None = None) -> Results:
    """Run every unit (resuming from ``out/units``); returns its :class:`Results`."""
    from ..errors import DatasetError
    from .units import Unit, evaluate_units, load_cached, say_damage

    check_angles(config.angles)
    datasets = load_cached(config.data, frames=config.frames, size=config.size, seed=config.seed)
    data_notes = say_damage(datasets)
    units, skipped = [], []
    for name, frames in datasets.items():
        for i in sample_indices(len(frames), config.samples):
            if frames[i].labels is None:
                raise DatasetError(f"dataset {name}: frame {frames[i].name} has no labels")
            why = _untrainable(frames[i], config.features)
            if why:  # as the sequence evaluation leaves out a frame it cannot train on, said
                skipped.append((f"dataset {name}, frame {frames[i].name}", why))
                continue
            for b in config.backends:
                units.append(Unit(f"{name}/frame{i}_{b}", name, (("index", i), ("backend", b)), config))
    if not units and skipped:  # no frame to score: the first one's reason
        raise DatasetError(f"{skipped[0][0]}: {skipped[0][1]}")
    notes = tuple(f"{where}: {why}; naive Bayes is trained on the frame itself, so it is not scored"
                  for where, why in skipped)
    for line in notes:
        sys.stderr.write(f"pcreg: note: {line}\n")
    results = evaluate_units(units, run_unit, config, summarise=summarise, out=out, force=force, executor=executor,
                             recorder=recorder, desc="rotation", show_progress=show_progress, kept=kept,
                             data_notes=data_notes)
    return replace(results, notes=notes) if notes else results


def _untrainable(frame, features) -> str | None:
    """Why naive Bayes cannot be trained on ``frame`` alone (its labels of one class, or all unknown), or None."""
    from ..classification.bayes import fit_classifier
    from ..errors import InputError

    try:
        fit_classifier([frame], features=features)
    except InputError as exc:
        return str(exc)
    return None


def summarise(config: RotationConfig, unit_results: list[dict]) -> Results:
    """results.json: per dataset and angle the mean over sampled frames (first backend at top level)."""
    import numpy as np

    from .units import angle_key, plain_config

    primary = config.backends[0]
    by_backend: dict = {b: {"datasets": {}} for b in config.backends}
    for b in config.backends:
        names = list(dict.fromkeys(u["dataset"] for u in unit_results))
        for name in names:
            us = [u for u in unit_results if u["dataset"] == name and u["backend"] == b]
            angles = {}
            for a in config.angles:
                key = angle_key(a)
                rows = [u["angles"][key] for u in us]
                cell = {k: float(np.mean([r[k] for r in rows])) for k in KEYS}
                ce = [r["corner_error"] for r in rows if r["corner_error"] is not None]
                cell.update(frames=len(rows), failed=sum(not r["registered"] for r in rows),
                            corner_error_median=float(np.median(ce)) if ce else None,
                            # the worst beside it: a frame registered a period off (a checkerboard turned 180 degrees,
                            # 619 px) was hidden behind the median of the others
                            corner_error_max=float(np.max(ce)) if ce else None,
                            seconds_register_median=float(np.median([r["seconds_register"] for r in rows])))
                angles[key] = cell
            by_backend[b]["datasets"][name] = {"frames": [u["name"] for u in us], "angles": angles}
    return Results("rotation", plain_config(config), {n: dict(d) for n, d in by_backend[primary]["datasets"].items()},
                   unit_results, primary_backend=primary, backends=by_backend)

