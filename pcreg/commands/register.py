"""Register a moving image to a reference image and print the transform T_ref_mov."""

from __future__ import annotations

import argparse
import sys

from ..registration.transforms import MODELS, with_article
from ._common import add_record_arguments, arg_float, arg_int, init_refusal, open_recorder, positive_int, print_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("reference", help="reference image (png, jpg, ...), its pixels as stored: an EXIF orientation "
                                     "is not applied")
    p.add_argument("moving", help="moving image, registered onto the reference")
    p.add_argument("--backend", choices=("reference", "open3d"), default="reference",
                   help="the ICP: pcreg's own (reference, the default) or Open3D's; the same algorithm")
    p.add_argument("--model", choices=MODELS + ("dense",), default="rigid",
                   help="motion model (default rigid); dense: the similarity refined by a dense field")
    p.add_argument("--levels", type=arg_int(1, 8), default=4, help="pyramid levels, 1..8 (default 4)")
    p.add_argument("--iterations", type=positive_int, default=14, help="ICP iterations per level (default 14)")
    p.add_argument("--init", default="auto", metavar="{auto,identity,center,FILE}",
                   help="auto (default): global rotation search; identity: start from no motion; center: from the image "
                        "centres aligned; FILE: a 3x3 text matrix T_ref_mov (a prior pose, odometry's), refined "
                        "instead of searching")
    p.add_argument("--max-distance", type=arg_float(0, 1e6, lo_open=True), default=2.5,
                   help="correspondence distance in px at full resolution (x 2^level; default 2.5)")
    p.add_argument("--refine", choices=("none", "point_to_line"), default="none",
                   help="finish: none (default) or point_to_line (reference backend only), which removes edge-sampling bias")
    p.add_argument("--min-inlier-ratio", type=arg_float(0, 1), default=None, metavar="R",
                   help="refuse (exit 3) below this share of tight inliers (default: the library's, 0.15); "
                        "0 turns the test off, and the checks that mark or refuse a result with it")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="WARPED.png", help="write the moving image warped onto the reference grid")
    add_record_arguments(p)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import cv2

    from ..errors import InputError, OutputError, RegistrationError
    from ..outputs import atomic_write_bytes, remove_leftovers
    from ..formats import read_image_file_and_damage
    from ..registration.clouds import cloud_pyramid, image_and_mask
    from ..registration.api import register
    from ..registration.config import RegisterConfig
    from ..registration.warp import warp

    _check_arguments(args)
    start = _start(args.init)
    options = {} if args.min_inlier_ratio is None else {"min_inlier_ratio": args.min_inlier_ratio or None}  # 0: off
    config = RegisterConfig.of(backend=args.backend, model=args.model, levels=args.levels, iterations=args.iterations,
                               init=args.init if start is None else "auto", max_correspondence_distance=args.max_distance,
                               refine=args.refine, **options)
    ref_stored, ref_damage = read_image_file_and_damage(args.reference)
    ref, ref_mask = image_and_mask(ref_stored, args.reference)  # transparent pixels are not matched
    stored, damage = read_image_file_and_damage(args.moving)  # decoded once: registered, and warped as stored by --out
    mov, mov_mask = image_and_mask(stored, args.moving)
    for path, mask in ((args.reference, ref_mask), (args.moving, mov_mask)):
        if not isinstance(mask, str) and args.model == "dense":  # "auto": no transparent pixel
            raise InputError(f"{path}: transparent pixels, which the dense model cannot leave out (it leaves black "
                             "padding out); flatten the image or use a global --model")
    if args.model == "dense" and ref.shape[:2] != mov.shape[:2]:
        raise InputError(f"{args.moving}: {mov.shape[1]}x{mov.shape[0]} px, the reference {args.reference} "
                         f"{ref.shape[1]}x{ref.shape[0]}: the dense model needs images of one size")
    with open_recorder(args, name=f"register {args.moving} -> {args.reference}",
                       inputs=(args.reference, args.moving, getattr(args, "init", None))) as rec:
        rec.set_frame(0)
        rec.log_config({k: v for k, v in vars(args).items() if not k.startswith("_")})
        rec.log_images(reference=ref, moving=mov)
        if rec.enabled:  # the clouds are made for the recording alone
            rc, mc = cloud_pyramid(ref, levels=1)[0], cloud_pyramid(mov, levels=1)[0]
            rec.log_clouds(reference_points=rc.points, reference_colors=rc.colors, moving_points=mc.points,
                           moving_colors=mc.colors)
        try:
            result = register(ref, mov, config=config, callback=rec.icp_callback(args.backend), reference_mask=ref_mask,
                              moving_mask=mov_mask, init=start)
        except (InputError, RegistrationError) as exc:  # "the reference image (16x16) is too small ...": name its file
            raise _refusal(exc, args, start, ((args.reference, ref_stored, ref_damage), (args.moving, stored, damage))) \
                from None
        warped = valid = None
        if args.out or rec.enabled:
            warped, valid = warp(mov, getattr(result, "field", result.matrix), shape=ref.shape)
        rec.log_transform(result.matrix)
        if getattr(result, "field", None) is not None:
            rec.log_dense(result.field, matrix=result.matrix, confidence=result.confidence)
        rec.log_images(warped=warped, valid_mask=valid)
        rec.log_text(repr(result))
    if args.out:
        png = not args.out.lower().endswith((".jpg", ".jpeg"))
        keep = png and _keeps_its_form(stored)
        if keep:  # a 16-bit, grey or transparent PNG keeps its depth and channels
            warped = warp(stored, getattr(result, "field", result.matrix), shape=ref.shape)[0]
        ok, buf = cv2.imencode(".png" if png else ".jpg", warped if keep else warped[:, :, ::-1])
        if not ok:
            raise OutputError(f"cannot encode {args.out}")
        out = Path(args.out)
        remove_leftovers(out.parent, [out.name])  # a temporary file of a register killed while it wrote this name
        atomic_write_bytes(out, buf.tobytes())
    notes = [*_notes(result, args.model, ((args.reference, ref_damage, ref), (args.moving, damage, mov))),
             *_dark_notes(((args.reference, ref_stored), (args.moving, stored)))]
    if args.json:
        # trusted: no check marked the result (null for a dense result, whose field no check judges)
        print_json({"ok": True, **result.to_dict(), "trusted": result.trusted, "notes": notes})
    else:
        print(result)
        summary = _summary(result, args.model, tested=config.plausibility.min_inlier_ratio is not None)
        if summary:
            print(summary)
    for note in notes:
        sys.stderr.write(f"pcreg: note: {note}\n")
    return 0


def _start(init: str):
    """``--init``'s 3x3 matrix when it names a file (None for a start the configuration names: ``auto``, ``identity``,
    ``center``, and ``global``, the library's other name of ``auto``): a text matrix, refused naming the file when it is
    not a 3x3 transform the model can hold."""
    from ..text_files import read_text_matrix
    from ..registration.config import INITS

    if init in INITS:
        return None
    return read_text_matrix(init, what="initial guess")


def _check_arguments(args: argparse.Namespace) -> None:
    """An :class:`~pcreg.errors.InputError` for a cloud given as an image, an ``--out`` that is not a free PNG or
    JPEG name, or a finish the backend does not run, before any image is read."""
    import os
    from pathlib import Path

    from ..cloud_reader import CLOUD_SUFFIXES
    from ..errors import InputError
    from ..outputs import check_output

    for path in (args.reference, args.moving):
        if Path(path).suffix.lower() in CLOUD_SUFFIXES:  # before "not an image", which leaves a cloud's user stuck
            raise InputError(f"{path}: a point cloud; pcreg register takes two images. Register two clouds with "
                             "pcreg crosscheck TARGET SOURCE (its reference row is pcreg's ICP) or pcreg.icp")
    if args.out is not None:
        if args.out.endswith(("/", os.sep)) or Path(args.out).suffix.lower() not in (".png", ".jpg", ".jpeg"):
            raise InputError(f"--out {args.out!r}: the warped image is written as PNG or JPEG; name it .png or .jpg")
        check_output(args.out, force=args.force, inputs=(args.reference, args.moving))
    if args.refine == "point_to_line" and args.backend != "reference":  # the library's refusal names its keywords
        raise InputError("--refine point_to_line is a reference-backend finish (Open3D's ICP here is point-to-point): "
                         "leave --refine out with --backend open3d, or give --backend reference")


def _refusal(exc: Exception, args: argparse.Namespace, start, images) -> Exception:
    """What ``register`` raises for ``exc``: the init's own refusal, or ``exc`` naming its file (``images``: each
    one's path, array as stored and damage); a refused registration notes what a result would of the files (an
    image turned by its EXIF orientation, damaged data)."""
    from ..errors import RegistrationError

    named = None if start is None else init_refusal(exc, args.init)
    if named is None:
        named = _naming_its_file(exc, [(path, stored) for path, stored, _ in images])
    if isinstance(named, RegistrationError):
        for note in _file_notes([(path, damage) for path, _, damage in images]):
            named.add_note(note)
    return named


def _naming_its_file(exc: Exception, images) -> Exception:
    """``exc`` of the same type with the file named, when it names "the reference image" or "the moving image"
    (``images``: each one's path and array as its file stores it); an image refused for having no edges says
    when its 16-bit values use only the lowest bits (:func:`pcreg.frame.low_bits_note`), and so does any other
    refused registration, first: nearly black, the images' edges are too faint to line up. A refusal's image that
    repeats itself is named by its file."""
    from ..errors import RegistrationError
    from ..frame import low_bits_note

    said = str(exc)
    for role, (path, stored) in zip(("the reference image", "the moving image"), images):
        said = said.replace(f"refused: {role} repeats itself", f"refused: {path} repeats itself")
        if said.startswith(role):
            dark = low_bits_note(stored) if said.startswith(f"{role} has no usable edges") else ""
            return type(exc)(f"{path}: {role} has no usable edges: {dark}" if dark else f"{path}: {said}")
    darks = [str(path) for path, stored in images if low_bits_note(stored)]
    if isinstance(exc, RegistrationError) and darks:  # briefly, so that the refusal's own advice stays on its line
        which = " and ".join(darks)
        return type(exc)(f"registration refused: {which} read{'s' if len(darks) == 1 else ''} nearly black (16-bit "
                         "values in the lowest bits: stretch them over the 16 bits or store the image as 8-bit); "
                         f"{said.removeprefix('registration refused: ')}")
    return exc if said == str(exc) else type(exc)(said)


def _dark_notes(images) -> list[str]:
    """What is said of each image (``images``: its path and array as its file stores it) whose 16-bit values use
    only the lowest bits (:func:`pcreg.frame.low_bits_note`), registered or refused."""
    from ..frame import low_bits_note

    return [f"{path}: {dark}" for path, stored in images if (dark := low_bits_note(stored))]


def _summary(result, model: str, *, tested: bool = True) -> str:
    """One line a person reads beside the result: the motion (rotation, scale, shift of the moving image's
    origin; the matrix alone for affine and projective) and the evidence, the share of edge points that line up
    against the share unrelated content would give (a registration is refused under
    :data:`~pcreg.registration.plausibility.CHANCE_FACTOR` times it, unless ``tested`` is False: the test is off).
    Empty for a result without evidence."""
    import math

    from ..registration.plausibility import CHANCE_FACTOR

    if getattr(result, "evidence", None) is None or getattr(result, "field", None) is not None:
        return ""
    m = result.matrix
    motion = f"{model} motion"
    if model in ("translation", "rigid", "similarity"):
        angle = math.degrees(math.atan2(m[1, 0], m[0, 0]))
        scale = math.sqrt(abs(m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]))
        motion += (f": rotation {angle:.2f} deg" + (f", scale {scale:.4f}" if model == "similarity" else "")
                   + f", shift ({m[0, 2]:.2f}, {m[1, 2]:.2f}) px")
    ratio, chance = result.inlier_ratio, result.chance_ratio
    times = f"{ratio / chance:.1f}x" if chance > 0 else "far above"
    limit = f"refused under {CHANCE_FACTOR:g}x" if tested else "no plausibility test: --min-inlier-ratio 0"
    return (f"{motion}; {100 * ratio:.1f}% of the moving edge points line up with the reference's, {times} the "
            f"{100 * chance:.1f}% unrelated content would give ({limit})")


def _notes(result, model: str, images) -> list[str]:
    """What ``pcreg register`` notes of a result it returns (on stderr, and in ``--json``'s ``"notes"``): the
    model check's and the features' disagreement, then of each image (``images``: its path, what its decoder said
    of damaged data, its array) damage, an EXIF orientation, and a pattern that repeats under a shift."""
    return [*_model_fit_notes(result, model), *_feature_notes(result),
            *_file_notes([(path, damage) for path, damage, _ in images]),
            *_repeat_notes([(path, image) for path, _, image in images], result)]


def _model_fit_notes(result, model: str) -> list[str]:
    """A note when a projective fit (refined from the result or from ORB's homography of the pair)
    aligns significantly more edge points, or as many and moves them far (:attr:`~pcreg.registration.result.RegistrationResult.model_fits`
    False): the transform is the model's best approximation of a view it cannot make, or off the alignment."""
    evidence = getattr(result, "evidence", None)  # a dense result has none: a field follows its similarity
    fit = None if evidence is None else evidence.model_fit
    if fit is None or fit.fits:
        return []
    return [f"the images differ by more than {with_article(model)} motion, or this result is off: a {fit.model} fit "
            f"aligns {100 * fit.inlier_ratio:.1f}% of the edge points against this result's "
            f"{100 * fit.result_inlier_ratio:.1f}% (at half size) and moves some by {fit.largest_shift_px:.1f} px "
            f"(--model {fit.model} registers such a view)"]


def _feature_notes(result) -> list[str]:
    """A note when the homography of the images' SIFT matches, strongly supported, puts points of the
    moving image more than 3 px from where a projective result does
    (:attr:`~pcreg.registration.result.RegistrationResult.features_agree` False)."""
    evidence = getattr(result, "evidence", None)
    if evidence is None or evidence.features is None or evidence.features.agree is not False:
        return []
    check = evidence.features
    return [f"the result disagrees with the images' feature matches: their homography ({check.inliers} of "
            f"{check.matches} SIFT matches, far more than chance gives) puts points where the matches are up to "
            f"{check.largest_shift_px:.1f} px from where the result does; the result may be wrong"]


def _file_notes(files, command: str = "registers") -> list[str]:
    """Notes for each image file (``files``: its path, and what its decoder said of damaged data it
    decoded around, or ""): such damage, and an EXIF orientation that has viewers show the image turned or
    mirrored (``T_ref_mov`` maps the pixels as stored, not the view a person sees; ``command``, what pcreg does
    with them, as the note says it)."""
    from ..formats import orientation_note

    notes = []
    for path, damage in dict(files).items():
        if damage:
            notes.append(f"{path}: its decoder reports damaged data ({damage}): part of the image "
                         "is the decoder's guess, and the result may be off")
        turned = orientation_note(path, command)
        if turned is not None:
            notes.append(turned)
    return notes


def _repeat_notes(images, result=None) -> list[str]:
    """A note when one of the images (``images``: each one's path and array, the reference first) repeats itself
    under a shift (``result.evidence.repeats``; without a result or its evidence, a dense one, checked here:
    :func:`~pcreg.registration.repetition.pair_repeats`): a motion that differs from the result by it aligns the
    images as well, so the result may be a period off."""
    from ..registration.repetition import pair_repeats

    evidence = getattr(result, "evidence", None)
    found = pair_repeats(images[0][1], images[1][1]) if evidence is None else evidence.repeats
    if found is None:
        return []
    path = images[0][0] if found.image == "reference" else images[1][0]
    dx, dy = found.shift_px
    return [f"{path} repeats itself: shifted by about ({dx:.0f}, {dy:.0f}) px it matches itself "
            f"(correlation {found.correlation:.2f}), so a motion that differs by such a shift aligns the images as well "
            "as this one, and the result may be a period off"]


def _keeps_its_form(stored) -> bool:
    """Whether the moving image, as its file stores it (OpenCV's channel order), is not the 8-bit colour the
    registration read (16 bits, grey, an alpha channel), so that a PNG of it warped keeps that form."""
    import numpy as np

    if stored.dtype not in (np.uint8, np.uint16):
        return False
    return not (stored.dtype == np.uint8 and stored.ndim == 3 and stored.shape[2] == 3)
