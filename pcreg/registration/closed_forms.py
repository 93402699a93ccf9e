"""The reference ICP's step: the closed forms of each motion model from weighted pairs, the pairs' robust
weights, and what the points must hold for a model (:func:`check_rank`, :func:`rank_problem`, :func:`pairs_needed`).
:mod:`pcreg.registration.reference` runs the loop around them."""

from __future__ import annotations

import math

import numpy as np

from .._jit import njit
from ..errors import RegistrationError
from .choices import WEIGHTS
from .transforms import apply, with_article

MIN_POINTS = {"translation": 1, "rigid": 2, "similarity": 2, "affine": 3, "projective": 4}
#: The same in 3-D: a rotation needs three points off one line, an affine map four off one plane (no projective model).
MIN_POINTS_3D = {"translation": 1, "rigid": 3, "similarity": 3, "affine": 4}


#: The unknowns of a step that takes one equation from a pair, point to line (2-D) by model; point to plane (3-D,
#: rigid) solves for six. With fewer pairs its system is singular whatever the pairs.
LINE_UNKNOWNS = {"translation": 2, "rigid": 3, "similarity": 4, "affine": 6, "projective": 8}


def pairs_needed(model: str, d: int, metric: str = "point_to_point") -> int:
    """The fewest matched pairs an ICP step of ``model`` takes in ``d`` dimensions (:data:`MIN_POINTS` in 2-D,
    :data:`MIN_POINTS_3D` in 3-D; a point-to-line or point-to-plane step a pair for each unknown, :data:`LINE_UNKNOWNS`):
    with fewer, a run stops where it is, not converged. (A point-to-plane step of four pairs solved as singular
    gave no motion, and the run said it converged at its start.)"""
    if metric == "point_to_line":
        return LINE_UNKNOWNS[model]
    if metric == "point_to_plane":
        return 6
    return MIN_POINTS[model] if d == 2 else MIN_POINTS_3D.get(model, 4)


# ---------------------------------------------------------------------------------------------------
# Closed-form estimators: weighted least squares of sum_i w_i |T(p_i) - q_i|^2
# ---------------------------------------------------------------------------------------------------

def _weighted_means(p: np.ndarray, q: np.ndarray, w: np.ndarray):
    ws = w.sum()
    mp = (w @ p) / ws
    mq = (w @ q) / ws
    return ws, mp, mq


def estimate_translation(p: np.ndarray, q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted mean displacement."""
    d = p.shape[1]
    _, mp, mq = _weighted_means(p, q, w)
    T = np.eye(d + 1)
    T[:d, d] = mq - mp
    return T


def estimate_umeyama(p: np.ndarray, q: np.ndarray, w: np.ndarray, *, with_scale: bool) -> np.ndarray:
    """Rigid or similarity transform by SVD (Umeyama 1991).

    Σ = Σ_i w_i (q_i - μ_q)(p_i - μ_p)^T / Σ w  (Eq. 38); σ_p² = Σ_i w_i |p_i - μ_p|² / Σ w (Eq. 36);
    the rest in :func:`umeyama_from_moments`.
    """
    ws, mp, mq = _weighted_means(p, q, w)
    pc = p - mp
    qc = q - mq
    cov = (qc * w[:, None]).T @ pc / ws
    var_p = float((w * np.einsum("ij,ij->i", pc, pc)).sum() / ws) if with_scale else 1.0
    return umeyama_from_moments(cov, var_p, mp, mq, with_scale=with_scale)


def umeyama_from_moments(cov: np.ndarray, var_p: float, mp: np.ndarray, mq: np.ndarray, *,
                         with_scale: bool) -> np.ndarray:
    """Umeyama's closed form from the cross-covariance Σ (d, d), the source variance σ_p² and the means.

    Σ = U D V^T; S = diag(1, …, 1, det(U) det(V)) (Eq. 43, the reflection guard); R = U S V^T (Eq. 40);
    c = tr(D S) / σ_p² (Eq. 42); t = μ_q - c R μ_p (Eq. 41). In 3-D, where rank Σ < 2 leaves R free about one
    direction, the least rotation that fits (:func:`_least_rotation`). In 2-D without the SVD (same result, no
    LAPACK call): for Σ = [[a, b], [c, d]] the rotation maximising tr(R^T Σ) is θ = atan2(c - b, a + d)
    and tr(D S) = hypot(a + d, c - b). Compiled (:func:`_umeyama`), the same code the ICP loop runs.
    """
    T, ok = _umeyama(np.ascontiguousarray(cov, dtype=np.float64), float(var_p),
                     np.ascontiguousarray(mp, dtype=np.float64), np.ascontiguousarray(mq, dtype=np.float64),
                     bool(with_scale))
    if not ok:
        raise RegistrationError("degenerate correspondences: all source points coincide")
    return T


@njit(cache=True)
def _det_sign(M: np.ndarray) -> float:
    """The sign of the determinant of an orthogonal matrix (+-1 up to rounding, so a 3x3's cofactor
    expansion has the sign of ``np.linalg.det``'s LU, without a LAPACK call)."""
    if M.shape[0] != 3:
        return 1.0 if np.linalg.det(M) >= 0 else -1.0
    a, b, c = M[0, 0], M[0, 1], M[0, 2]
    d, e, f = M[1, 0], M[1, 1], M[1, 2]
    g, h, i = M[2, 0], M[2, 1], M[2, 2]
    return 1.0 if a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) >= 0 else -1.0


#: Σ's second singular value at or below this share of its first counts as zero (:func:`_umeyama`).
RANK_TOLERANCE = 1e-12


@njit(cache=True)
def _least_rotation(u: np.ndarray, v: np.ndarray, determined: bool, R: np.ndarray) -> None:
    """Write into ``R`` (3, 3) the rotation of least angle that maps the unit vector ``v`` onto ``u``
    (Rodrigues: R = I + K + K² / (1 + v·u), K the cross-product matrix of v × u); a half turn about an axis
    perpendicular to ``v`` when they are opposite; the identity when not ``determined``.

    Umeyama's rotation maximises tr(R^T Σ); it is unique only when rank Σ >= d - 1 (Umeyama 1991, section
    III). With rank Σ = 1, Σ = σ u v^T, every rotation with R v = u attains the maximum and the SVD's null
    space picks one at random (pairs whose source or target points lie on one line; ICP's first step from far
    away, where every source point is nearest to two target points). The least of them moves the source no
    more than the pairs ask, as the 2-D closed form's atan2 does; with Σ = 0 that is no rotation."""
    for i in range(3):
        for j in range(3):
            R[i, j] = 1.0 if i == j else 0.0
    if not determined:
        return
    c = u[0] * v[0] + u[1] * v[1] + u[2] * v[2]
    a = np.array([v[1] * u[2] - v[2] * u[1], v[2] * u[0] - v[0] * u[2], v[0] * u[1] - v[1] * u[0]])
    if 1.0 + c > 1e-12:
        K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
        R += K + (K @ K) / (1.0 + c)
        return
    m = np.argmin(np.abs(v))  # opposite: a half turn about the axis perpendicular to v nearest a coordinate axis
    e = np.zeros(3)
    e[m] = 1.0
    n = e - v[m] * v  # e minus its part along v (e @ v is v[m]: e is one-hot)
    n /= math.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
    for i in range(3):
        for j in range(3):
            R[i, j] = 2.0 * n[i] * n[j] - (1.0 if i == j else 0.0)


@njit(cache=True)
def _umeyama(cov, var_p, mp, mq, with_scale):
    """:func:`umeyama_from_moments`, compiled: (T, True), or (identity, False) when ``with_scale`` and
    the source variance is not positive (every source point in one place)."""
    d = cov.shape[0]
    T = np.eye(d + 1)
    if with_scale and not var_p > 0:
        return T, False
    R = np.empty((d, d))
    k = 1.0
    if d == 2:
        a, b, c, e = cov[0, 0], cov[0, 1], cov[1, 0], cov[1, 1]
        th = math.atan2(c - b, a + e)
        cos, sin = math.cos(th), math.sin(th)
        R[0, 0], R[0, 1], R[1, 0], R[1, 1] = cos, -sin, sin, cos
        if with_scale:
            k = math.hypot(a + e, c - b) / var_p
    else:
        U, D, Vt = np.linalg.svd(cov)
        S = np.ones(d)
        # U and V are orthogonal: their determinants are +-1, and only the sign of the product is used
        if _det_sign(U) * _det_sign(Vt) < 0:
            S[d - 1] = -1.0
        if d == 3 and not D[1] > RANK_TOLERANCE * D[0]:  # rank < d - 1: the turn about one direction is free
            _least_rotation(U[:, 0], Vt[0], D[0] > 0, R)
            S[:] = 1.0
        else:
            for i in range(d):
                for j in range(d):
                    acc = 0.0
                    for m in range(d):
                        acc += U[i, m] * S[m] * Vt[m, j]
                    R[i, j] = acc
        if with_scale:
            k = (D * S).sum() / var_p
    for i in range(d):
        acc = 0.0
        for j in range(d):
            T[i, j] = k * R[i, j]
            acc += T[i, j] * mp[j]
        T[i, d] = mq[i] - acc
    return T, True


def estimate_horn_quaternion(p: np.ndarray, q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """3-D rigid transform by the unit quaternion of Horn (1987), as used by Besl & McKay (1992).

    N (Horn's Eq. 26 / Besl-McKay's Q(Σ)) is the symmetric 4x4 matrix built from the cross-covariance
    M = Σ w (p - μ_p)(q - μ_q)^T; the eigenvector of its largest eigenvalue is the rotation quaternion.
    That eigenvector is unique only when rank M >= 2: where the pairs fix one direction only (rank M = 1, as
    :data:`RANK_TOLERANCE` decides for Umeyama's step), the largest eigenvalue is double and any turn about that
    direction fits as well; the step then takes the least rotation that fits, as Umeyama's does
    (:func:`_least_rotation`), and none when M = 0.
    """
    if p.shape[1] != 3:
        raise RegistrationError("the quaternion closed form is for 3-D clouds")
    ws, mp, mq = _weighted_means(p, q, w)
    M = ((p - mp) * w[:, None]).T @ (q - mq) / ws
    U, D, Vt = np.linalg.svd(M.T)  # Umeyama's Σ = M^T
    if not D[1] > RANK_TOLERANCE * D[0]:
        R = np.empty((3, 3))
        _least_rotation(np.ascontiguousarray(U[:, 0]), np.ascontiguousarray(Vt[0]), bool(D[0] > 0), R)
        return _rigid(R, mp, mq)
    Sxx, Sxy, Sxz = M[0]
    Syx, Syy, Syz = M[1]
    Szx, Szy, Szz = M[2]
    N = np.array([
        [Sxx + Syy + Szz, Syz - Szy, Szx - Sxz, Sxy - Syx],
        [Syz - Szy, Sxx - Syy - Szz, Sxy + Syx, Szx + Sxz],
        [Szx - Sxz, Sxy + Syx, -Sxx + Syy - Szz, Syz + Szy],
        [Sxy - Syx, Szx + Sxz, Syz + Szy, -Sxx - Syy + Szz],
    ])
    vals, vecs = np.linalg.eigh(N)
    q0, qx, qy, qz = vecs[:, np.argmax(vals)]
    R = np.array([
        [q0 * q0 + qx * qx - qy * qy - qz * qz, 2 * (qx * qy - q0 * qz), 2 * (qx * qz + q0 * qy)],
        [2 * (qy * qx + q0 * qz), q0 * q0 - qx * qx + qy * qy - qz * qz, 2 * (qy * qz - q0 * qx)],
        [2 * (qz * qx - q0 * qy), 2 * (qz * qy + q0 * qx), q0 * q0 - qx * qx - qy * qy + qz * qz],
    ])
    return _rigid(R, mp, mq)


def _rigid(R: np.ndarray, mp: np.ndarray, mq: np.ndarray) -> np.ndarray:
    """The 3-D rigid transform of rotation ``R`` that maps the mean ``mp`` onto ``mq``."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = mq - R @ mp
    return T


def estimate_affine(p: np.ndarray, q: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Weighted linear least squares of [A | t] (p - μ_p centred for conditioning)."""
    d = p.shape[1]
    _, mp, mq = _weighted_means(p, q, w)
    pc, qc = p - mp, q - mq
    sw = np.sqrt(w)[:, None]
    X, *_ = np.linalg.lstsq(pc * sw, qc * sw, rcond=None)
    A = X.T
    T = np.eye(d + 1)
    T[:d, :d] = A
    T[:d, d] = mq - A @ mp
    return T


def _normalising(p: np.ndarray) -> np.ndarray:
    m = p.mean(axis=0)
    s = np.sqrt(2.0) / max(np.mean(np.linalg.norm(p - m, axis=1)), 1e-12)
    return np.array([[s, 0, -s * m[0]], [0, s, -s * m[1]], [0, 0, 1.0]])


#: How :func:`estimate_projective` solves the DLT: ``"svd"``, the right singular vector of the weighted 2N x 9 matrix
#: (every registration of the projective model); ``"normal"``, the eigenvector of its 9 x 9 normal matrix (the model
#: check's refinement, :func:`~pcreg.registration.plausibility.model_fit`).
DLT_SOLVES = ("svd", "normal")


def estimate_projective(p: np.ndarray, q: np.ndarray, w: np.ndarray, *, solve: str = "svd") -> np.ndarray:
    """Homography by the normalised weighted DLT (Hartley & Zisserman 2003, Alg. 4.2).

    solve : ``"svd"``, the smallest right singular vector of the 2N x 9 matrix A; ``"normal"``, the smallest
        eigenvector of AᵀA (9 x 9, from the moments of the normalised points, :func:`_dlt_normal`: a fraction of
        the SVD's time on thousands of pairs). The same vector: on Hartley-normalised points AᵀA is well
        conditioned, and the two homographies agree to about 1e-13 relative."""
    if solve == "normal":
        return _homography(*_dlt_normal(p, q, np.sqrt(w)))
    Np, Nq = _normalising(p), _normalising(q)
    pn, qn = apply(Np, p), apply(Nq, q)
    x, y = pn[:, 0], pn[:, 1]
    u, v = qn[:, 0], qn[:, 1]
    one, zero = np.ones_like(x), np.zeros_like(x)
    A1 = np.column_stack([x, y, one, zero, zero, zero, -u * x, -u * y, -u])
    A2 = np.column_stack([zero, zero, zero, x, y, one, -v * x, -v * y, -v])
    sw = np.sqrt(w)[:, None]
    A = np.vstack([A1 * sw, A2 * sw])
    # with 4 pairs A is 8 x 9: the reduced SVD's Vt has 8 rows and leaves out the null vector, the exact solution
    _, _, Vt = np.linalg.svd(A, full_matrices=A.shape[0] < A.shape[1])
    return _homography(Vt[-1], Np, Nq)


#: A DLT solution ``h`` whose 3 x 3 determinant is at or below this share of |h|³ is singular: it maps the plane
#: onto a line or a point (every pair on one line leaves such an ``h`` in the null space; fits to 1e-33 there,
#: against 0.08 to 0.18 for the homographies of the tests).
SINGULAR_HOMOGRAPHY = 1e-12


def _homography(h: np.ndarray, Np: np.ndarray, Nq: np.ndarray) -> np.ndarray:
    """The DLT's solution ``h`` (9,) on normalised points back in the points' own coordinates, H[2, 2] = 1; a
    :class:`RegistrationError` when ``h`` is singular (:data:`SINGULAR_HOMOGRAPHY`) or sends the origin to infinity."""
    h3 = h.reshape(3, 3)
    if not abs(np.linalg.det(h3)) > SINGULAR_HOMOGRAPHY * float(np.sqrt(h @ h)) ** 3:
        raise RegistrationError("registration refused: degenerate homography: the pairs fit only a singular one, which "
                                "maps the plane onto a line (their source points on one line?)")
    H = np.linalg.inv(Nq) @ h3 @ Np
    if abs(H[2, 2]) < 1e-12:
        raise RegistrationError("registration refused: degenerate homography: it sends the origin to infinity")
    return H / H[2, 2]


def _dlt_normal(p: np.ndarray, q: np.ndarray, sw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The DLT's solution from its normal matrix AᵀA, and the normalisations (:func:`_normalising`'s) of ``p``
    and ``q``: with a = √w (x, y, 1) of a normalised p, a row pair of A is (aᵀ, 0, -u aᵀ) and (0, aᵀ, -v aᵀ)
    (u, v: the normalised q), so AᵀA's 3 x 3 blocks are the moments Σ a aᵀ, Σ u a aᵀ, Σ v a aᵀ and
    Σ (u² + v²) a aᵀ, all in one product of the N x 9 matrix (a, u a, v a) with itself."""
    mp, mq = p.mean(axis=0), q.mean(axis=0)
    dp, dq = p - mp, q - mq
    sp = np.sqrt(2.0) / max(np.mean(np.sqrt(np.einsum("ij,ij->i", dp, dp))), 1e-12)
    sq = np.sqrt(2.0) / max(np.mean(np.sqrt(np.einsum("ij,ij->i", dq, dq))), 1e-12)
    K = np.empty((len(p), 9))
    np.multiply(dp, (sp * sw)[:, None], out=K[:, :2])
    K[:, 2] = sw
    dq *= sq
    np.multiply(K[:, :3], dq[:, :1], out=K[:, 3:6])
    np.multiply(K[:, :3], dq[:, 1:2], out=K[:, 6:9])
    G = K.T @ K
    S, Su, Sv = G[:3, :3], G[:3, 3:6], G[:3, 6:9]
    M = np.zeros((9, 9))
    M[:3, :3] = M[3:6, 3:6] = S
    M[:3, 6:], M[3:6, 6:] = -Su, -Sv
    M[6:, :3], M[6:, 3:6] = -Su.T, -Sv.T
    M[6:, 6:] = G[3:6, 3:6] + G[6:9, 6:9]
    _, vecs = np.linalg.eigh(M)
    Np = np.array([[sp, 0, -sp * mp[0]], [0, sp, -sp * mp[1]], [0, 0, 1.0]])
    Nq = np.array([[sq, 0, -sq * mq[0]], [0, sq, -sq * mq[1]], [0, 0, 1.0]])
    return vecs[:, 0], Np, Nq


@njit(cache=True, error_model="numpy")
def _dlt_normal_pairs(p, q, match, w):
    """:func:`estimate_projective`'s ``solve="normal"``, compiled: ``(H, 0)``, or ``(H, 4)`` for a degenerate
    homography (singular, :data:`SINGULAR_HOMOGRAPHY`, or ``|h33|`` < 1e-12) and ``(H, 1)`` for a normal matrix that
    is not finite. The pairs are ``p[t] -> q[match[t]]`` weighted ``w[t]`` where ``match[t] >= 0``, in ``p``'s order
    (the compiled projective ICP's matches, :func:`~pcreg.registration.reference._projective_loop`); the same sums as :func:`_dlt_normal`
    (the normalisations unweighted, the blocks of AᵀA weighted), summed one pair at a time."""
    k, mp0, mp1, mq0, mq1 = 0, 0.0, 0.0, 0.0, 0.0
    for t in range(p.shape[0]):
        j = match[t]
        if j >= 0:
            k += 1
            mp0 += p[t, 0]
            mp1 += p[t, 1]
            mq0 += q[j, 0]
            mq1 += q[j, 1]
    mp0, mp1, mq0, mq1 = mp0 / k, mp1 / k, mq0 / k, mq1 / k
    rp, rq = 0.0, 0.0
    for t in range(p.shape[0]):
        j = match[t]
        if j >= 0:
            rp += math.sqrt((p[t, 0] - mp0) ** 2 + (p[t, 1] - mp1) ** 2)
            rq += math.sqrt((q[j, 0] - mq0) ** 2 + (q[j, 1] - mq1) ** 2)
    sp, sq = math.sqrt(2.0) / max(rp / k, 1e-12), math.sqrt(2.0) / max(rq / k, 1e-12)
    S = np.zeros((4, 3, 3))  # the blocks Σ a aᵀ, Σ u a aᵀ, Σ v a aᵀ, Σ (u² + v²) a aᵀ
    a = np.empty(3)
    for t in range(p.shape[0]):
        j = match[t]
        if j >= 0:
            sw = math.sqrt(w[t])
            a[0], a[1], a[2] = (p[t, 0] - mp0) * (sp * sw), (p[t, 1] - mp1) * (sp * sw), sw
            u, v = (q[j, 0] - mq0) * sq, (q[j, 1] - mq1) * sq
            for r in range(3):
                for c in range(3):
                    aa = a[r] * a[c]
                    S[0, r, c] += aa
                    S[1, r, c] += (a[r] * u) * a[c]
                    S[2, r, c] += (a[r] * v) * a[c]
                    S[3, r, c] += (u * a[r]) * (u * a[c]) + (v * a[r]) * (v * a[c])
    M = np.zeros((9, 9))
    for r in range(3):
        for c in range(3):
            M[r, c] = M[3 + r, 3 + c] = S[0, r, c]
            M[r, 6 + c] = M[6 + c, r] = -S[1, r, c]
            M[3 + r, 6 + c] = M[6 + c, 3 + r] = -S[2, r, c]
            M[6 + r, 6 + c] = S[3, r, c]
    H = np.eye(3)
    if not np.isfinite(M).all():
        return H, 1
    h = np.linalg.eigh(M)[1][:, 0]
    if not abs(np.linalg.det(h.reshape(3, 3))) > SINGULAR_HOMOGRAPHY:  # a unit vector: |h|³ = 1 (:func:`_homography`)
        return H, 4
    # H = Nq⁻¹ h Np, with Np = [[sp, 0, -sp mp], [0, sp, ...], [0, 0, 1]] and Nq⁻¹ = [[1/sq, 0, mq], ...]
    for r in range(3):
        g0, g1, g2 = h[3 * r], h[3 * r + 1], h[3 * r + 2]
        H[r, 0], H[r, 1], H[r, 2] = g0 * sp, g1 * sp, g2 - sp * (g0 * mp0 + g1 * mp1)
    for c in range(3):
        H[0, c], H[1, c] = H[0, c] / sq + mq0 * H[2, c], H[1, c] / sq + mq1 * H[2, c]
    if abs(H[2, 2]) < 1e-12:
        return H, 4
    return H / H[2, 2], 0


def estimate(p: np.ndarray, q: np.ndarray, w: np.ndarray, model: str, *, rotation: str = "svd",
             dlt: str = "svd") -> np.ndarray:
    """Closed-form update for one motion model from weighted correspondences p_i -> q_i (``dlt``: how the
    projective model's DLT is solved, :data:`DLT_SOLVES`)."""
    if model == "translation":
        return estimate_translation(p, q, w)
    if model == "rigid":
        if rotation == "quaternion" and p.shape[1] == 3:
            return estimate_horn_quaternion(p, q, w)
        return estimate_umeyama(p, q, w, with_scale=False)
    if model == "similarity":
        return estimate_umeyama(p, q, w, with_scale=True)
    if model == "affine":
        return estimate_affine(p, q, w)
    if model == "projective":
        return estimate_projective(p, q, w, solve=dlt)
    raise RegistrationError(f"unknown model {model!r}")


def robust_weights(dist: np.ndarray, kind: str, *, scale: float | None = None, trim_fraction: float = 0.9) -> np.ndarray:
    """Weights of correspondences from their distances.

    ``trimmed`` keeps the closest ``trim_fraction`` (Chetverikov et al. 2002, trimmed ICP); ``huber``
    (k = 1.345 σ) and ``tukey`` (c = 4.685 σ) are the M-estimators with the usual 95%-efficiency
    constants, σ = 1.4826 MAD of the distances unless ``scale`` is given.
    """
    if kind == "none" or dist.size == 0:
        return np.ones_like(dist)
    if kind == "trimmed":
        if not 0 < trim_fraction <= 1:
            raise RegistrationError(f"trim_fraction must be in (0, 1], got {trim_fraction}")
        k = max(1, int(np.ceil(trim_fraction * dist.size)))
        w = np.zeros_like(dist)
        w[np.argsort(dist, kind="stable")[:k]] = 1.0
        return w
    sigma = scale if scale is not None else 1.4826 * float(np.median(np.abs(dist)))
    sigma = max(sigma, 1e-12)
    if kind == "huber":
        cut = 1.345 * sigma
        return np.where(dist <= cut, 1.0, cut / np.maximum(dist, 1e-300))
    if kind == "tukey":
        c = 4.685 * sigma
        return np.where(dist < c, (1.0 - (dist / c) ** 2) ** 2, 0.0)
    raise RegistrationError(f"unknown robust weight {kind!r}; choose one of {', '.join(WEIGHTS)}")


def spread(points: np.ndarray) -> tuple[np.ndarray, float]:
    """The singular values of ``points`` (N, d) about their mean, largest first, and the least value that is more than
    rounding: 1e-9 of the largest, or what float64's rounding of the coordinates gives of itself (each coordinate off
    by up to ``eps |x|``: 100 points of a line 1 unit long, 1e6 from the origin, are 1e-9 thick by rounding alone;
    measured on lines and planes 1e3 to 1e9 from the origin, 3 to 10,000 points, at most 0.43 ``eps max|x| sqrt(N)``,
    taken 4 times). The mean is taken out twice: its own rounding, a shift of every point, would read as a direction
    (a cloud of 10,000 points 1e9 away, 1e-3 across, a line read as a plane)."""
    c = points - points.mean(axis=0)
    c -= c.mean(axis=0)
    sv = np.linalg.svd(c, compute_uv=False)
    largest = float(sv[0]) if sv.size else 0.0
    rounding = 4.0 * np.finfo(np.float64).eps * float(np.abs(points).max(initial=0.0)) * np.sqrt(len(points))
    return sv, max(1e-9 * largest, rounding, 1e-300)


def rank_problem(points: np.ndarray, model: str) -> str | None:
    """Why ``points`` (N, d) cannot determine the ``model``, or None: too few, or coincident, collinear (3-D:
    the rotation about their line is free) or coplanar where the model needs more. The reason
    :func:`check_rank` raises, and the cross-check marks its rows with."""
    n, d = points.shape
    need = pairs_needed(model, d)
    if n < need:
        return f"{n} point(s) are too few for the {model} model (needs at least {need})"
    if model == "translation":
        return None
    sv, least = spread(points)
    extent = sv[0] if sv.size else 0.0
    same = bool(np.all(points == points[:1]))  # equal points: their mean's rounding (0.1 - 0.1000...01) is no line
    rank = int(np.sum(sv > least)) if extent > 0 and not same else 0
    needed_rank = {"rigid": d - 1, "similarity": d - 1, "affine": d, "projective": 2}[model]
    if rank < needed_rank:
        what = "coincident" if rank == 0 else ("collinear" if rank == 1 else "coplanar")
        return f"the points are {what}: they cannot determine {with_article(model)} transform"
    return None


def rotation_problem(p: np.ndarray, q: np.ndarray) -> str | None:
    """Why the pairs ``p_i -> q_i`` (K, d) leave a rigid step's rotation undetermined, or None: the source or the
    target points are too few, coincident or (3-D) on one line (:func:`rank_problem`), or their cross-covariance
    has rank below d - 1 (:data:`RANK_TOLERANCE`, where the reference's step takes the least rotation): the pairs
    fix one direction, or none, and every turn about it fits them as well."""
    for name, points in (("source", p), ("target", q)):
        problem = rank_problem(points, "rigid")
        if problem is not None:
            return (f"their {name} points {problem.removeprefix('the points ')}" if problem.startswith("the points ")
                    else f"their {name} points: {problem}")
    d = p.shape[1]
    sv = np.linalg.svd((q - q.mean(axis=0)).T @ (p - p.mean(axis=0)), compute_uv=False)
    if d == 3 and not sv[1] > RANK_TOLERANCE * sv[0]:
        return "their cross-covariance has rank 1: they fix one direction and any turn about it fits as well"
    return None


def check_rank(points: np.ndarray, model: str) -> None:
    """Raise :class:`RegistrationError` when the points cannot determine the model (:func:`rank_problem`)."""
    problem = rank_problem(points, model)
    if problem is not None:
        raise RegistrationError(problem)


#: The models whose steps can shrink the source (their linear part is not a rotation).
SHRINKING_MODELS = ("similarity", "affine", "projective")
#: Below this scale a refused result is said to have shrunk the source (a collapse runs to 1e-30 and less).
SHRUNK = 1e-3


def paired_targets(T: np.ndarray, source: np.ndarray, target: np.ndarray, max_distance: float) -> np.ndarray:
    """The indices (sorted, each once) of the ``target`` points that ``source`` moved by ``T`` pairs with: each
    moved point's nearest, closer than ``max_distance``."""
    from .kdtree import KDTreeIndex
    from .transforms import apply as move

    with np.errstate(all="ignore"):  # a projective T may send a point through infinity: no match for it
        moved = move(T, source)
    finite = np.all(np.isfinite(moved), axis=1)
    _, idx = KDTreeIndex(target).nearest(moved[finite], max_distance)
    return np.unique(idx[idx >= 0])


def check_rotation_pairs(fitness: float, source_points: int, model: str, d: int, max_distance: float, *,
                         converged: bool, metric: str = "point_to_point") -> None:
    """Raise when a ``rigid`` ICP that ``converged`` (or moved the source at its last scale, stopped by its
    iterations) ended with fewer pairs (``fitness`` x ``source_points``
    matched within ``max_distance``) than fix a rotation in ``d`` dimensions (:func:`pairs_needed`: 2 in 2-D, 3 in
    3-D): about them any turn fits as well, and the result's is arbitrary. The reference's step does not take such
    pairs (its run stops there, not converged, and is not refused here); Open3D's takes any non-empty set: two pairs
    of 52 source points in 3-D gave a half turn about a skew axis, "converged", inlier RMSE 1.7e-15. A
    point-to-plane (point-to-line) step takes one equation a pair: it needs a pair an unknown (``metric``)."""
    need = pairs_needed(model, d, metric)
    pairs = int(round(fitness * source_points))
    if model != "rigid" or not converged or pairs >= need:
        return
    raise RegistrationError(
        f"registration refused: at the result only {pairs} source point(s) of {source_points} lie within the "
        f"correspondence distance {max_distance:g} of a target point, and a rigid motion in {d}-D needs {need} to fix "
        f"its rotation{'' if metric == 'point_to_point' else ' (one equation a pair, ' + metric.replace('_', ' ') + ')'}: "
        "the turn about them is arbitrary (give an init nearer the answer, or a larger "
        "max_correspondence_distance)")


def check_paired_rotation(T: np.ndarray, source: np.ndarray, target: np.ndarray, max_distance: float) -> None:
    """Raise when a rigid point-to-point ICP's result ``T`` (``T_target_source``) is held by pairs that leave its
    rotation undetermined (:func:`rotation_problem`: in 3-D, the target points the moved source points match,
    nearest and closer than ``max_distance``, on one line, or a cross-covariance of rank 1). The clouds themselves
    may determine it: an L-shaped source whose one arm alone reaches the target (the rest beyond the distance) came
    back turned 17 or 126 degrees about that arm from two starts, each converged with the same fitness and inlier
    RMSE; a line 1e-7 thick and 10 long, a half turn off with Open3D's step."""
    from .kdtree import KDTreeIndex
    from .transforms import apply as move

    moved = move(T, source)
    _, idx = KDTreeIndex(target).nearest(moved, max_distance)
    paired = idx >= 0
    problem = rotation_problem(moved[paired], target[idx[paired]])
    if problem is not None:
        raise RegistrationError(
            f"registration refused: at the result the {int(paired.sum())} pair(s) within the correspondence distance "
            f"{max_distance:g} leave the rotation undetermined ({problem}); give an init nearer the answer, or a larger "
            "max_correspondence_distance")


def check_support(T: np.ndarray, source: np.ndarray, target: np.ndarray, max_distance: float, model: str, *,
                  converged: bool) -> None:
    """Raise when an ICP's result ``T`` (``T_target_source``) of a ``model`` that can shrink the source
    (:data:`SHRINKING_MODELS`) is held by pairs that cannot determine it: the target points its moved source
    points match (nearest, closer than ``max_distance``) are too few or coincident, collinear or coplanar
    for the model (:func:`check_rank`), and the run says it ``converged`` or shrank the source below
    :data:`SHRUNK`. (A run that had too few pairs from its start stops there, not converged, and is not
    refused here.)

    That is the fixed point a similarity (or affine) ICP falls into when it shrinks the source onto one target
    point: each step matches every source point to that point, and the least-squares step shrinks it further
    (a random 3-D cloud scaled by 2.5, turned 30 degrees and moved by (0.5, 1, -2) ended with a determinant
    of 1e-102, a fitness of 1, an inlier RMSE of 0 and converged, with either backend's step)."""
    if model not in SHRINKING_MODELS:
        return
    matched = target[paired_targets(T, source, target, max_distance)]
    try:
        check_rank(matched, model)
    except RegistrationError as exc:
        d = T.shape[0] - 1
        scale = abs(float(np.linalg.det(T[:d, :d]))) ** (1 / d)
        if not converged and not scale < SHRUNK:
            return
        shrank = "; the ICP shrank the source onto them" if scale < SHRUNK else ""
        raise RegistrationError(
            f"registration refused: at the result (scale {scale:.3g}) the source's pairs reach {len(matched)} target "
            f"point(s), which cannot determine {with_article(model)} transform ({exc}){shrank}; give an init nearer the answer, or "
            "another max_correspondence_distance") from None
