"""The ICP steps that read the target's normals, linearised about the identity: point-to-line (2-D, every
motion model) and point-to-plane (3-D, rigid, as Open3D's ``TransformationEstimationPointToPlane``).
:func:`~pcreg.registration.reference.icp_reference` takes them for ``metric="point_to_line"`` and
``metric="point_to_plane"``."""

from __future__ import annotations

import numpy as np

__all__ = ["estimate_point_to_line", "estimate_point_to_plane", "normals_problem"]


def normals_problem(normals: np.ndarray) -> str | None:
    """Why ``normals`` (M, d) cannot fix a motion, or None: one of length 0 (no direction), or all of them in
    one plane or along one line (the motion along the rest is free: point-to-plane or point-to-line steps
    would stop where they start, or drift there, and call it converged)."""
    lengths = np.linalg.norm(normals, axis=1)
    if not np.all(lengths > 0):
        return f"{int(np.count_nonzero(lengths == 0))} normal(s) of length 0"
    spread = np.linalg.svd(normals / lengths[:, None], compute_uv=False)
    if spread[-1] <= 1e-6 * spread[0]:
        return (f"the normals span {int(np.count_nonzero(spread > 1e-6 * spread[0]))} of {normals.shape[1]} "
                "directions: the motion along the rest is not fixed by them")
    return None


def estimate_point_to_line(p: np.ndarray, q: np.ndarray, n: np.ndarray, w: np.ndarray, model: str) -> np.ndarray:
    """2-D point-to-line step (the planar case of Chen & Medioni 1992's point-to-plane).

    Minimises Σ w ((U(p) - q) · n)^2 over a small update U linearised about the identity, in
    coordinates centred on the weighted mean of p and scaled to unit RMS radius (for conditioning).
    The projective update is U = I + dH with h33 = 1, linearised as
    Δx = a x + b y + c - x (g x + h y), Δy = d x + e y + f - y (g x + h y).
    Rigid and similarity rotations are rebuilt exactly from the solved angle.
    """
    mp = (w @ p) / w.sum()
    scale = float(np.sqrt((w @ np.sum((p - mp) ** 2, axis=1)) / w.sum())) or 1.0
    N = np.array([[1 / scale, 0, -mp[0] / scale], [0, 1 / scale, -mp[1] / scale], [0, 0, 1.0]])
    pn, qn = (p - mp) / scale, (q - mp) / scale
    x, y = pn[:, 0], pn[:, 1]
    nx, ny = n[:, 0], n[:, 1]
    r0 = np.einsum("ij,ij->i", pn - qn, n)
    perp = ny * x - nx * y  # d/dθ of (R p)·n at θ = 0
    radial = x * nx + y * ny
    cols = {"translation": [nx, ny],
            "rigid": [perp, nx, ny],
            "similarity": [perp, radial, nx, ny],
            "affine": [x * nx, y * nx, nx, x * ny, y * ny, ny],
            "projective": [x * nx, y * nx, nx, x * ny, y * ny, ny, -x * radial, -y * radial]}
    J = np.column_stack(cols[model])
    JTJ = (J * w[:, None]).T @ J
    trace = float(np.trace(JTJ))  # the damping relative to it: normals of any length (their residuals' unit) alike
    JTJ += np.eye(J.shape[1]) * 1e-9 * (trace if trace > 0 else 1.0)
    v = np.linalg.solve(JTJ, -(J * w[:, None]).T @ r0)
    U = np.eye(3)
    if model == "translation":
        U[:2, 2] = v
    elif model in ("rigid", "similarity"):
        k = 1.0 + v[1] if model == "similarity" else 1.0
        U[:2, :2] = k * np.array([[np.cos(v[0]), -np.sin(v[0])], [np.sin(v[0]), np.cos(v[0])]])
        U[:2, 2] = v[-2:]
    else:
        U[0, :] += v[0:3]
        U[1, :] += v[3:6]
        if model == "projective":
            U[2, :2] = v[6:8]
    return np.linalg.inv(N) @ U @ N


#: Pairs whose mean lies more than this many of their spreads (RMS radius) from the point a step is taken about
#: are taken about that mean instead, the one rule of far clouds (real-world coordinates): here a point-to-plane
#: step is linearised about the origin (as Open3D's) unless the pairs lie that far from it (about an origin 5e6
#: away the 6x6 system's condition number passed 1e12 and the step was the identity; solved better, the rotation
#: about that far origin overshot by the square of its angle times the distance, and the run diverged); the
#: reference ICP's moments are summed about their mean past it (:func:`~pcreg.registration.reference.icp_reference`).
RECENTRE = 100.0


def estimate_point_to_plane(p: np.ndarray, q: np.ndarray, n: np.ndarray, w: np.ndarray) -> np.ndarray:
    """3-D rigid point-to-plane step (Chen & Medioni 1992), linearised as Open3D's
    ``TransformationEstimationPointToPlane``: minimises Σ w ((p - q) · n + ω · (p × n) + t · n)^2 over the
    small rotation ω and the translation t (the 6x6 normal equations, in the clouds' own coordinates),
    then builds the rotation Rz(ω_z) Ry(ω_y) Rx(ω_x). A singular system gives no motion (the identity),
    as Open3D's solver does when it fails. Pairs whose mean lies more than :data:`RECENTRE` spreads from the origin
    are linearised about that mean instead (the rotation turns about it): clouds in real-world coordinates."""
    total = float(w.sum())
    if not total > 0:  # no weight: the system is singular about any point, the identity
        return _point_to_plane_about_origin(p, q, n, w)
    c = (w @ p) / total
    spread2 = float(w @ np.sum((p - c) ** 2, axis=1)) / total
    if float(c @ c) <= RECENTRE * RECENTRE * spread2:
        return _point_to_plane_about_origin(p, q, n, w)
    C = np.eye(4)
    C[:3, 3] = c
    return C @ _point_to_plane_about_origin(p - c, q - c, n, w) @ np.linalg.inv(C)


def _equilibrated_cond(JTJ: np.ndarray) -> float:
    """Condition number of ``JTJ`` with its rows and columns scaled to a unit diagonal (Jacobi), so that it does
    not depend on the clouds' units: the rotation's columns scale with the coordinates and the translation's do
    not (a cloud 1e-6 across had a condition number of 1e12 and more, well posed); inf for a zero diagonal."""
    diagonal = np.diag(JTJ)
    if not np.all(diagonal > 0):
        return float("inf")
    s = 1.0 / np.sqrt(diagonal)
    return float(np.linalg.cond(JTJ * np.outer(s, s)))


def _point_to_plane_about_origin(p: np.ndarray, q: np.ndarray, n: np.ndarray, w: np.ndarray) -> np.ndarray:
    r = np.einsum("ij,ij->i", p - q, n)
    J = np.hstack([np.cross(p, n), n])
    Jw = J * w[:, None]
    JTJ, JTr = Jw.T @ J, Jw.T @ r
    try:
        x = np.linalg.solve(JTJ, -JTr)
    except np.linalg.LinAlgError:
        return np.eye(4)
    if not np.all(np.isfinite(x)) or _equilibrated_cond(JTJ) > 1e12:
        return np.eye(4)
    (cx, cy, cz), (sx, sy, sz) = np.cos(x[:3]), np.sin(x[:3])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    Ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    Rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    U = np.eye(4)
    U[:3, :3] = Rz @ Ry @ Rx
    U[:3, 3] = x[3:]
    return U
