"""The attitude at the output edges: REP-103 frames and the orientation covariance of a Bingham.

Inside, attitudes rotate body FRD into world NED (``q_ned_frd``, w, x, y, z).
ROS (REP-103) wants world ENU and body FLU; Foxglove's 3D view is upright in
ENU too. The conversion is one explicit composition::

    q_enu_flu = Q_ENU_NED (x) q_ned_frd (x) Q_FRD_FLU

``Q_ENU_NED`` maps NED vectors to ENU (x east = y NED, y north = x NED, z up =
-z NED: half a turn about (1, 1, 0)/sqrt 2); ``Q_FRD_FLU`` maps FLU vectors to
FRD (half a turn about x). Both are their own inverses up to sign.

The orientation covariance is the covariance of the small world-frame
rotation ``delta`` that takes the published orientation ``m`` to the true one,
``q = exp(delta / 2) (x) m`` (ROS: "fixed axes", rotation about the parent
frame's X, Y, Z). Its vector part is linear in ``q``: ``vec(q (x) m*) = A q``
with ``A`` the last three rows of the right-multiplication matrix of ``m*``,
and ``delta = 2 vec(q (x) m*)`` to first order, so

    Cov(delta) = 4 A E[q q^T] A^T

with ``E[q q^T] = M diag(omega) M^T`` the Bingham's inertia (saddlepoint paper,
eq. 1). It is invariant to the sign of ``q`` and needs no sampling; the tests
check it against a Monte Carlo of exact Bingham draws (``core.sampling``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core import quaternion as quat

if TYPE_CHECKING:
    from core.normalization import Method

__all__ = [
    "BODY_FRAME",
    "DISPLAY_FRAME",
    "Q_ENU_NED",
    "Q_FRD_FLU",
    "R_ENU_NED",
    "TRUTH_OFFSET_NED_M",
    "WORLD_FRAME",
    "body_transforms",
    "enu_flu_from_ned_frd",
    "flu_from_frd",
    "orientation_covariance_enu",
    "orientation_covariance_ned",
]

_H = math.sqrt(0.5)
Q_ENU_NED = np.array([0.0, _H, _H, 0.0])
"""Rotates NED vectors into ENU (w, x, y, z)."""
Q_FRD_FLU = np.array([0.0, 1.0, 0.0, 0.0])
"""Rotates FLU vectors into FRD (w, x, y, z)."""
R_ENU_NED = quat.to_matrix(Q_ENU_NED)
"""``v_enu = R_ENU_NED @ v_ned``."""


def enu_flu_from_ned_frd(q_ned_frd: ArrayLike) -> NDArray[np.float64]:
    """``q_enu_flu = Q_ENU_NED (x) q_ned_frd (x) Q_FRD_FLU``, sign chosen with w >= 0."""
    q = quat.multiply(quat.multiply(Q_ENU_NED, np.asarray(q_ned_frd, dtype=float)), Q_FRD_FLU)
    return -q if q[0] < 0 else q


def flu_from_frd(v_frd: ArrayLike) -> tuple[float, float, float]:
    """A body vector from FRD to FLU (x, -y, -z)."""
    x, y, z = (float(c) for c in v_frd)
    return (x, -y, -z)


def orientation_covariance_ned(
    M: ArrayLike, Z: ArrayLike, q_ned_frd: ArrayLike, method: Method = "saddlepoint"
) -> NDArray[np.float64]:
    """3x3 covariance (rad^2) of the NED-frame rotation from ``q_ned_frd`` to the truth, under ``Bingham(M, Z)``."""
    from core.bingham import Bingham  # here, not at the top: the recorder's process uses this module's frames only

    inertia = Bingham(M, Z).inertia(method)
    A = quat.right_matrix(quat.conjugate(q_ned_frd))[1:, :]
    cov = 4.0 * A @ inertia @ A.T
    return 0.5 * (cov + cov.T)


def orientation_covariance_enu(
    M: ArrayLike, Z: ArrayLike, q_ned_frd: ArrayLike, method: Method = "saddlepoint"
) -> NDArray[np.float64]:
    """The same covariance about the ENU axes: ``R_ENU_NED C R_ENU_NED^T`` (the error rotation's
    vector part is rotated by ``Q_ENU_NED``; the body-side ``Q_FRD_FLU`` cancels in ``q (x) m*``)."""
    return R_ENU_NED @ orientation_covariance_ned(M, Z, q_ned_frd, method) @ R_ENU_NED.T


# -- the frame tree of the Foxglove views (live and recorded) -----------------------------------
DISPLAY_FRAME = "enu"
"""Root of the 3D view: z up, so the scene is upright."""
WORLD_FRAME = "ned"
"""The fuser's world frame, a child of ``enu`` rotated by ``Q_ENU_NED``; poses are in it."""
BODY_FRAME = "body"
"""The estimate's body frame (FRD), at the origin of ``ned``."""
TRUTH_OFFSET_NED_M = (0.0, 1.0, 0.0)
"""The truth's (or reference's) body frame sits 1 m east of the estimate's, so the two triads do not overlap."""


def body_transforms(child_frame: str, q_ned_frd: ArrayLike, translation_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0),
                    ) -> list[tuple[str, str, tuple[float, float, float], tuple[float, float, float, float]]]:
    """``(parent, child, translation xyz, rotation xyzw)`` of ``enu -> ned`` and ``ned -> child_frame``.

    Foxglove's FrameTransform maps a point of the child into the parent (rotation, then
    translation), so each rotation is the child's attitude in its parent: ``Q_ENU_NED`` and
    ``q_ned_frd``. The fixed ``enu -> ned`` edge goes with every body so that any one message
    places the body in the upright display frame.
    """
    w0, x0, y0, z0 = (float(c) for c in Q_ENU_NED)
    w, x, y, z = (float(c) for c in q_ned_frd)
    return [
        (DISPLAY_FRAME, WORLD_FRAME, (0.0, 0.0, 0.0), (x0, y0, z0, w0)),
        (WORLD_FRAME, child_frame, tuple(float(c) for c in translation_ned_m), (x, y, z, w)),  # type: ignore[misc]
    ]
