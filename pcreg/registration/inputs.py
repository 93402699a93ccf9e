"""The point clouds and initial guesses that enter an ICP: :func:`check_cloud` for :func:`pcreg.icp` (and the
cloud readers), :func:`backend_inputs` at the door of each backend's ICP
(:func:`~pcreg.registration.reference.icp_reference`, :func:`~pcreg.registration.open3d_icp.icp_open3d`), which
researchers call directly. Bad input is an :class:`~pcreg.errors.InputError`, never numpy's, numba's or
Open3D's own exception, nor a result computed from NaN or from mismatched dimensions.
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..validation import check_point_count, check_unmasked, real_matrix

MAX_COORDINATE = 1e9  # squared distances stay far from overflow and float64 keeps sub-mm steps at 1e6 m
#: A cloud that spans less than this (but more than nothing) is refused: the squared distances of a millionth of it
#: stay above float64's smallest normal number (2.2e-308); below, they underflow to 0, and a cloud 1e-200 across
#: turned 10 degrees came back unturned with an inlier RMSE of 0.
MIN_EXTENT = 1e-140


def check_cloud(points: np.ndarray, name: str, *, limit: int | None = None) -> np.ndarray:
    """(N, 2|3) finite float64 copy of ``points`` within the point limit (``limit``) or an :class:`InputError`."""
    if getattr(points, "dtype", None) is not None and np.dtype(points.dtype).kind == "b":
        raise InputError(f"{name}: true/false values are a mask, not coordinates")
    if getattr(points, "dtype", None) is not None and np.dtype(points.dtype).kind in "USV":  # numpy parses "1.5"
        raise InputError(f"{name}: text or bytes ({np.dtype(points.dtype)}), not numeric coordinates (convert them first)")
    if type(points).__module__.startswith("open3d") and hasattr(points, "points"):
        raise InputError(f"{name}: an Open3D {type(points).__name__}, not an array; pass np.asarray(cloud.points)")
    check_unmasked(points, name)
    try:
        if np.iscomplexobj(points):  # numpy would drop the imaginary part with a warning
            raise TypeError
        p = np.array(points, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):  # OverflowError: a Python int beyond float64
        raise InputError(f"{name}: not a numeric array") from None
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise InputError(f"{name}: expected an (N, 2) or (N, 3) array of points, got shape {p.shape}")
    if p.shape[0] == 0:
        raise InputError(f"{name}: the cloud is empty")
    check_point_count(p.shape[0], name, limit=limit)
    _check_values(p, name)
    return p


def _check_values(p: np.ndarray, name: str) -> None:
    if not np.all(np.isfinite(p)):
        bad = int((~np.isfinite(p)).any(axis=1).sum())
        raise InputError(f"{name}: {bad} point(s) have NaN or inf coordinates")
    big = float(np.max(np.abs(p)))
    if big > MAX_COORDINATE:
        raise InputError(f"{name}: coordinates up to {big:.3g} are out of range (|x| <= {MAX_COORDINATE:g}; "
                         "shift the cloud towards the origin)")
    extent = _extent(p)
    if 0 < extent < MIN_EXTENT:
        raise InputError(f"{name}: the cloud spans {extent:.3g}, under {MIN_EXTENT:g}: its squared distances underflow "
                         "to 0 (scale the clouds up alike)")


def _extent(p: np.ndarray) -> float:
    """The cloud's largest span along one axis, ``max(np.ptp(p, axis=0))``, one column at a time: numpy reduces an
    (N, d) array along its long axis 30 times slower (1.4 ms against 0.04 at 20,000 points), and every ICP call of
    :func:`~pcreg.register` checks both clouds (14 ms of its 85)."""
    return max(float(p[:, axis].max() - p[:, axis].min()) for axis in range(p.shape[1]))


def _backend_cloud(points, name: str) -> np.ndarray:
    """``points`` itself when it is already an (N, 2|3) float64 array (no copy: the ICP's numbers stay those
    of the caller's array), checked finite and in range; anything else through :func:`check_cloud`."""
    if (type(points) is np.ndarray and points.dtype == np.float64 and points.ndim == 2
            and points.shape[1] in (2, 3) and points.shape[0] > 0):
        _check_values(points, name)
        return points
    return check_cloud(points, name)


def backend_inputs(source, target, init, *, who: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(source, target, init)`` of one backend's ICP run (``who`` names it), checked: both clouds
    (N, 2|3) finite float64 of one dimension d, ``init`` a finite (d+1, d+1) matrix (None: the identity).
    Without this a 2-D source and a 3-D target were registered against each other as if they matched, a NaN
    source point was counted as a point without a pair, a NaN ``init`` came back as the result, and a
    wrong shape was numpy's IndexError or Open3D's TypeError."""
    src, tgt = _backend_cloud(source, "source"), _backend_cloud(target, "target")
    d = src.shape[1]
    if tgt.shape[1] != d:
        raise InputError(f"{who}: source is {d}-D but target is {tgt.shape[1]}-D")
    if init is None:
        return src, tgt, np.eye(d + 1)
    T = real_matrix(init, f"{who}: init must be a {d + 1}x{d + 1} matrix of numbers", f"{who}: init")
    if T.shape != (d + 1, d + 1):
        raise InputError(f"{who}: init must be a {d + 1}x{d + 1} matrix for {d}-D clouds, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise InputError(f"{who}: init has NaN or inf entries")
    return src, tgt, T
