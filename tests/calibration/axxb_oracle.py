"""Test oracle: a numpy port of the five closed-form AX = XB methods of OpenCV's ``cv2.calibrateHandEye``.

Production code calls OpenCV (:mod:`calibration.axxb`). This port was written when the opencv-python 5.0.0
wheels did not expose ``calibrateHandEye`` (opencv/opencv#29565) and is kept as an independent check of
what OpenCV returns: tests/calibration/test_axxb.py compares both with values recorded from OpenCV 4.12.
It follows the same papers with OpenCV's formulation (all view pairs i < j, the same linear systems, the
same normalisations):

- Tsai & Lenz 1989 (modified Rodrigues vectors, then translation by least squares),
- Park & Martin 1994 (rotation from the log-map correlation matrix),
- Horaud & Dornaika 1995 (unit quaternion as an eigenvector),
- Andreff, Horaud & Espiau 1999 (Kronecker-product linear system, rotation and translation together),
- Daniilidis 1998 (dual quaternions, SVD).

Quaternions take the sign with w >= 0 (as OpenCV does since 4.10, opencv/opencv#24897), and Tsai uses only
the view pairs whose rotation lies between about 17 and 116 degrees (the same filter as that fix).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from calibration.axxb import LinearMethod, relative_motions
from calibration.errors import CalibrationError
from perception.transforms import make_X

FloatArray = NDArray[np.float64]


def calibrate_hand_eye_numpy(
    X_base_tool: Sequence[ArrayLike] | FloatArray, X_camera_board: Sequence[ArrayLike] | FloatArray, *, method: str
) -> FloatArray:
    """(4, 4) ``X_tool_camera`` by the numpy port of one of OpenCV's methods (same inputs as
    :func:`calibration.axxb.calibrate_hand_eye_linear`)."""
    Hg = np.asarray(X_base_tool, dtype=np.float64)
    Hc = np.asarray(X_camera_board, dtype=np.float64)
    A, B = relative_motions(Hg, Hc)
    return _NUMPY_METHODS[LinearMethod(method)](A, B)


def _skew(v: FloatArray) -> FloatArray:
    """(..., 3, 3) cross-product matrices of (..., 3) vectors."""
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def _quat_wxyz(R: FloatArray) -> FloatArray:
    """(..., 4) unit quaternions ``[w, x, y, z]`` with w >= 0 of (..., 3, 3) rotations."""
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()  # scalar-last
    q = np.concatenate([q[:, 3:], q[:, :3]], axis=1)
    q[q[:, 0] < 0] *= -1.0
    return q.reshape(*R.shape[:-2], 4)


def _rot_from_quat_wxyz(q: FloatArray) -> FloatArray:
    q = np.asarray(q, dtype=np.float64)
    return Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()


def _qmul(s: FloatArray, t: FloatArray) -> FloatArray:
    """Hamilton product of ``[w, x, y, z]`` quaternions."""
    w = s[0] * t[0] - s[1:] @ t[1:]
    v = s[0] * t[1:] + t[0] * s[1:] + np.cross(s[1:], t[1:])
    return np.concatenate([[w], v])


def _translation_given_rotation(A: FloatArray, B: FloatArray, R: FloatArray) -> FloatArray:
    """Least-squares t of ``(I - R_A) t = t_A - R t_B`` stacked over all pairs."""
    C = (np.eye(3) - A[:, :3, :3]).reshape(-1, 3)
    d = (A[:, :3, 3] - B[:, :3, 3] @ R.T).reshape(-1)
    t, *_ = np.linalg.lstsq(C, d, rcond=None)
    return np.asarray(t, dtype=np.float64)


# |2 sin(θ/2)| bounds of the motions Tsai uses: θ between about 17 and 116 degrees.
_TSAI_P_MIN = 0.3
_TSAI_P_MAX = 1.7
_TSAI_DEG_MIN = float(np.degrees(2.0 * np.arcsin(_TSAI_P_MIN / 2.0)))
_TSAI_DEG_MAX = float(np.degrees(2.0 * np.arcsin(_TSAI_P_MAX / 2.0)))


def _tsai(A: FloatArray, B: FloatArray) -> FloatArray:
    # Modified Rodrigues vectors 2 sin(θ/2) n; skew(Pa + Pb) x = Pb - Pa (Tsai & Lenz eq. 12).
    Pa = 2.0 * _quat_wxyz(A[:, :3, :3])[:, 1:]
    Pb = 2.0 * _quat_wxyz(B[:, :3, :3])[:, 1:]
    # Like OpenCV >= 4.10 (opencv/opencv#24897), keep only informative motions: tiny rotations
    # have ill-defined axes and ones near 180 degrees blow up the linear system.
    na, nb = np.linalg.norm(Pa, axis=1), np.linalg.norm(Pb, axis=1)
    keep = (na > _TSAI_P_MIN) & (na < _TSAI_P_MAX) & (nb > _TSAI_P_MIN) & (nb < _TSAI_P_MAX)
    if np.count_nonzero(keep) < 2:
        raise CalibrationError(
            f"Tsai: only {np.count_nonzero(keep)} of {len(keep)} view pairs rotate between "
            f"{_TSAI_DEG_MIN:.0f} and {_TSAI_DEG_MAX:.0f} deg; include larger rotations"
        )
    A, B, Pa, Pb = A[keep], B[keep], Pa[keep], Pb[keep]
    x, *_ = np.linalg.lstsq(_skew(Pa + Pb).reshape(-1, 3), (Pb - Pa).reshape(-1), rcond=None)
    P = 2.0 * x / np.sqrt(1.0 + x @ x)  # eq. 14
    n2 = P @ P
    R = (1.0 - n2 / 2.0) * np.eye(3) + 0.5 * (np.outer(P, P) + np.sqrt(4.0 - n2) * _skew(P))
    # (R_A - I) t = R t_B - t_A (eq. 15) is the same system as in _translation_given_rotation.
    return make_X(R, _translation_given_rotation(A, B, R))


def _park(A: FloatArray, B: FloatArray) -> FloatArray:
    a = Rotation.from_matrix(A[:, :3, :3]).as_rotvec()
    b = Rotation.from_matrix(B[:, :3, :3]).as_rotvec()
    M = b.T @ a  # sum of b a^T
    eigval, eigvec = np.linalg.eigh(M.T @ M)
    R = eigvec @ np.diag(1.0 / np.sqrt(eigval)) @ eigvec.T @ M.T  # (M^T M)^(-1/2) M^T
    return make_X(R, _translation_given_rotation(A, B, R))


def _horaud(A: FloatArray, B: FloatArray) -> FloatArray:
    qa = _quat_wxyz(A[:, :3, :3])
    qb = _quat_wxyz(B[:, :3, :3])
    S = np.zeros((4, 4))
    for a, b in zip(qa, qb, strict=True):
        w, x, y, z = a
        Q = np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])  # a * q
        w, x, y, z = b
        W = np.array([[w, -x, -y, -z], [x, w, z, -y], [y, -z, w, x], [z, y, -x, w]])  # q * b
        S += (Q - W).T @ (Q - W)
    _, eigvec = np.linalg.eigh(S)
    R = _rot_from_quat_wxyz(eigvec[:, 0])
    return make_X(R, _translation_given_rotation(A, B, R))


def _orthonormalize(R: FloatArray) -> FloatArray:
    """Nearest rotation to a scaled, noisy 3x3 matrix (unit determinant scale, then SVD)."""
    det = np.linalg.det(R)
    if abs(det) < np.finfo(np.float32).eps:
        raise CalibrationError("Andreff: the estimated rotation is singular; the views are degenerate")
    R = np.cbrt(np.sign(det) / abs(det)) * R
    U, _, Vt = np.linalg.svd(R)
    out = U @ Vt
    if np.linalg.det(out) < 0:
        out = U @ np.diag([1.0, 1.0, -1.0]) @ Vt
    return np.asarray(out, dtype=np.float64)


def _andreff(A: FloatArray, B: FloatArray) -> FloatArray:
    # Unknowns: the 9 entries of R (row-major) and t. R_A R R_B^T = R and R t_B + (I - R_A) t = t_A.
    m = A.shape[0]
    M = np.zeros((12 * m, 12))
    rhs = np.zeros(12 * m)
    for k in range(m):
        Ra, ta = A[k, :3, :3], A[k, :3, 3]
        Rb, tb = B[k, :3, :3], B[k, :3, 3]
        M[12 * k : 12 * k + 9, :9] = np.eye(9) - np.kron(Ra, Rb)
        M[12 * k + 9 : 12 * k + 12, :9] = np.kron(np.eye(3), tb.reshape(1, 3))
        M[12 * k + 9 : 12 * k + 12, 9:] = np.eye(3) - Ra
        rhs[12 * k + 9 : 12 * k + 12] = ta
    sol, *_ = np.linalg.lstsq(M, rhs, rcond=None)
    return make_X(_orthonormalize(sol[:9].reshape(3, 3)), sol[9:])


def _dual_quat(H: FloatArray) -> tuple[FloatArray, FloatArray]:
    q = _quat_wxyz(H[:3, :3])
    q_dual = 0.5 * _qmul(np.concatenate([[0.0], H[:3, 3]]), q)
    return q, q_dual


def _daniilidis(A: FloatArray, B: FloatArray) -> FloatArray:
    m = A.shape[0]
    T = np.zeros((6 * m, 8))
    for k in range(m):
        qa, qa_d = _dual_quat(A[k])
        qb, qb_d = _dual_quat(B[k])
        a, b, a_d, b_d = qa[1:], qb[1:], qa_d[1:], qb_d[1:]
        # Daniilidis eq. 31: [a-b, [a+b]x, 0, 0; a'-b', [a'+b']x, a-b, [a+b]x] [q; q'] = 0
        T[6 * k : 6 * k + 3, 0] = a - b
        T[6 * k : 6 * k + 3, 1:4] = _skew(a + b)
        T[6 * k + 3 : 6 * k + 6, 0] = a_d - b_d
        T[6 * k + 3 : 6 * k + 6, 1:4] = _skew(a_d + b_d)
        T[6 * k + 3 : 6 * k + 6, 4] = a - b
        T[6 * k + 3 : 6 * k + 6, 5:8] = _skew(a + b)
    _, _, Vt = np.linalg.svd(T)
    v7, v8 = Vt[6], Vt[7]
    u1, w1, u2, w2 = v7[:4], v7[4:], v8[:4], v8[4:]
    # λ1 v7 + λ2 v8 with |q| = 1 and q·q' = 0 (eqs. 34, 35), s = λ1 / λ2.
    qa_, qb_, qc_ = u1 @ w1, u1 @ w2 + u2 @ w1, u2 @ w2
    disc = np.sqrt(max(qb_ * qb_ - 4.0 * qa_ * qc_, 0.0))
    best_s, best_val = 0.0, -np.inf
    for s in ((-qb_ + disc) / (2.0 * qa_), (-qb_ - disc) / (2.0 * qa_)):
        val = s * s * (u1 @ u1) + 2.0 * s * (u1 @ u2) + u2 @ u2
        if val > best_val:
            best_s, best_val = s, val
    lam2 = np.sqrt(1.0 / best_val)
    dq = best_s * lam2 * v7 + lam2 * v8
    q, q_dual = dq[:4], dq[4:]
    R = _rot_from_quat_wxyz(q)
    t = 2.0 * _qmul(q_dual, q * np.array([1.0, -1.0, -1.0, -1.0]))[1:]
    return make_X(R, t)


_NUMPY_METHODS: dict[LinearMethod, Callable[[FloatArray, FloatArray], FloatArray]] = {
    LinearMethod.TSAI: _tsai,
    LinearMethod.PARK: _park,
    LinearMethod.HORAUD: _horaud,
    LinearMethod.ANDREFF: _andreff,
    LinearMethod.DANIILIDIS: _daniilidis,
}
