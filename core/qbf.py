"""Second-order quaternion Bingham filter: orientation and rotational velocity from orientation observations.

Glover and Kaelbling, "Tracking 3-D Rotations with the Quaternion Bingham
Filter" (QBF paper, MIT-CSAIL-TR-2013-005), sec. 3-4. That paper already
writes quaternions (w, x, y, z) with the Hamilton product ``q o r`` = "rotate
by r, then by q" -- the project's order and :func:`core.quaternion.multiply`
-- so no conversion is needed at this boundary.

The second-order discrete quaternion Bingham process (sec. 3) is

* ``x_n = v_{n-1} o x_{n-1}``: the orientation advances by the discrete
  rotational velocity ``v`` (a world-frame rotation per step);
* ``v_n = w_n o u_n o v_{n-1}``: the velocity changes by the control ``u_n``
  (a rotational acceleration, identity for "constant velocity") and by
  process noise ``w_n ~ Bingham``;
* ``y_n = z_n o x_n``: the orientation is observed through noise
  ``z_n ~ Bingham``.

The filter (sec. 4, "Second-order QBF") keeps independent Bingham marginals
``B_x`` and ``B_v`` (assumed density filtering) and uses only the
:class:`~core.bingham.Bingham` operations of sec. 5: rotation by a fixed
quaternion, inversion, product of densities and moment-matched composition
(A.9.2).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from core import quaternion as quat
from core.bingham import Bingham
from core.normalization import Method

__all__ = ["QuaternionBinghamFilter", "observation_likelihood"]


def observation_likelihood(observation: ArrayLike, noise: Bingham) -> Bingham:
    """``f(y | x)`` for ``y = z o x`` as a Bingham density in ``x`` (QBF paper, sec. 4).

    ``x = z^-1 o y``, so the likelihood is ``Bingham(x; Lambda_o, V_o^-1 o
    y)``: the noise inverted, then rotated on the right by ``y``. It depends
    on ``y`` only up to sign, like every Bingham.
    """
    return noise.inverse().rotate_right(quat.as_quaternion(observation))


class QuaternionBinghamFilter:
    """Second-order QBF (QBF paper, sec. 4): Bingham marginals over orientation and velocity.

    ``orientation`` and ``velocity`` are the priors ``B_x0`` and ``B_v0``
    (the paper's ping-pong experiment, sec. 6, starts from
    ``Bingham.uniform()`` and a weak ``Bingham.from_mode(IDENTITY, (-3, -3,
    -3))``). ``process_noise`` is ``w``'s distribution and
    ``observation_noise`` is ``z``'s; both usually have their mode at the
    identity. ``method`` chooses the normalization used by every moment match.
    """

    def __init__(
        self,
        orientation: Bingham,
        velocity: Bingham,
        process_noise: Bingham,
        observation_noise: Bingham,
        method: Method = "saddlepoint",
    ) -> None:
        self._x = orientation
        self._v = velocity
        self.process_noise = process_noise
        self.observation_noise = observation_noise
        self.method: Method = method

    @property
    def orientation(self) -> Bingham:
        """Marginal posterior ``B_x_n`` of the orientation."""
        return self._x

    @property
    def velocity(self) -> Bingham:
        """Marginal of the velocity ``v_n`` that will carry ``x_n`` to ``x_{n+1}``."""
        return self._v

    @property
    def estimate(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Modes ``(orientation, velocity)``, each (w, x, y, z) with ``w >= 0``."""
        return self._x.mode, self._v.mode

    def step(self, observation: ArrayLike, control: ArrayLike | None = None) -> None:
        """Fuse the observation ``y_n`` of ``x_n``, then apply the control ``u_n`` to the velocity.

        Both marginals are computed from the time ``n - 1`` pair (sec. 4):

        * ``B_x_n = f(y_n | x_n) . (B_v_{n-1} o B_x_{n-1})``;
        * ``B_v_n = f_w o u_n o (B_v_{n-1} . (f(y_n | x_n) o B_x_{n-1}^-1))``:
          the likelihood of ``v_{n-1} = x_n o x_{n-1}^-1``, moment-matched by
          composition, multiplied into the velocity prior, rotated by the
          control and composed with the process noise.
        """
        likelihood = observation_likelihood(observation, self.observation_noise)
        x_prev, v_prev = self._x, self._v
        self._x = v_prev.compose(x_prev, self.method).product(likelihood)
        velocity_evidence = likelihood.compose(x_prev.inverse(), self.method)
        v_post = v_prev.product(velocity_evidence)
        if control is not None:
            v_post = v_post.rotate_left(control)
        self._v = self.process_noise.compose(v_post, self.method)
