"""Ball orientation per flash and the spin of a pitched ball (SPEC J1, seed section 4.4).

Input: for every strobe flash ``k`` (time ``times[k]``), the painted markers found on that ball
image, each as a **direction from the ball centre** in the world frame with its marker type
(:class:`MarkerObservations`). A marker triangulated by a stereo pair gives the direction
``(X - c) / |X - c|`` directly; a marker seen by one camera only gives a pixel ray, which meets
the ball sphere (known centre and radius) on the visible hemisphere:
:meth:`MarkerObservations.from_rays` turns it into a direction.

Rotations are ``ball2world``: ``u_world = R u_ball``; a marker ``j`` of the layout
(:class:`stillcap.ball.layout.BallLayout`) appears at ``R_k m_j`` at flash ``k``.

Two estimators return the same :class:`SpinResult`:

- :func:`fit_spin_seed`, the seed's method: per flash, ``R_k`` minimises
  ``E = a1 sum_i D_M(i)^2 + a2 sum_{j in x,y,z} D_A(j)^2`` (``D_M`` the angle from observed
  marker ``i`` to the nearest model marker of its type, ``D_A`` the angle between the ball
  axes of ``R_k`` and of the prediction ``R_{k-1}`` turned once more by the last relative
  rotation; ``a2 = 0`` for the first two orientations) with Powell's method over Euler angles;
  the relative rotations ``R_k R_{k-1}^T`` give axis-angle pairs, the spin axis is their mean
  and the rate their angle times the strobe frequency.
- :func:`fit_spin`, one constant spin over all flashes: ``R(t) = exp([w] (t - t0)) R0`` with
  ``R0`` and ``w`` (rad/s, world frame) fitted by robust least squares
  (``scipy.optimize.least_squares``) to the angles between every observed marker and the
  rotated model marker of its type it is assigned to (nearest, re-assigned until stable);
  then a plain least-squares polish on the inliers gives the covariance and the 1-sigma of
  the spin rate and axis.

Aliasing: with flashes every ``1/f`` s the rotation between flashes is only known modulo a full
turn, so both methods return the *principal* spin, whose rotation per interval is at most half
a turn (at most ``f / 2`` revolutions per second: 2400 rpm at 80 Hz). :mod:`stillcap.ball.alias`
enumerates the other candidates and picks one with a second strobe rate or the flight's
curvature; ``fit_spin(..., spin_init=candidate)`` then refits at that alias.

Where things are (private modules, the names below are the public face):

- ``_observations``: :class:`MarkerObservations`, :func:`rays_to_directions`,
  :func:`strobe_period` and the fits' input checks;
- ``_so3``: rotation helpers (exponential map, left Jacobian, Kabsch, rotation angles, mean
  and consensus rotations);
- ``_flash``: :func:`orient_flash` and :class:`FlashOrientation` (one flash, no prior);
- ``_result``: :class:`SpinResult` and ``RPM_PER_RAD_S``;
- ``_global``: :func:`fit_spin` (residuals, covariance, starting points, the coarse grid's
  rotation cache);
- ``_seed``: :func:`fit_spin_seed` (the seed's Powell fit);
- ``_simulate``: :func:`simulate_observations`.
"""

from stillcap.ball.orientation._flash import FlashOrientation, orient_flash
from stillcap.ball.orientation._global import fit_spin
from stillcap.ball.orientation._observations import (MarkerObservations, direction_information, rays_to_directions,
                                                  strobe_period)
from stillcap.ball.orientation._result import RPM_PER_RAD_S, SpinResult
from stillcap.ball.orientation._seed import fit_spin_seed
from stillcap.ball.orientation._simulate import simulate_observations

__all__ = ["RPM_PER_RAD_S", "FlashOrientation", "MarkerObservations", "SpinResult", "direction_information", "fit_spin",
           "fit_spin_seed",
           "orient_flash", "rays_to_directions", "simulate_observations", "strobe_period"]
