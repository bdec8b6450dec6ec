"""Line and arc landmarks: parameter forms, frames, per-beam ranges and measurement models.

A line in the plane is held in its **Hessian normal form** ``(rho, alpha)``: the points ``q`` of
the line satisfy ``q . (cos alpha, sin alpha) = rho``, with ``rho >= 0`` the line's distance from
the frame's origin and ``alpha`` the direction of its normal, wrapped to (-pi, pi]. It is the
default form because it has no special case: every line, vertical ones included, has bounded
parameters that change continuously as the line moves or turns (except across the frame's
origin, where the normal flips to keep ``rho >= 0``; a sensor never sees a line through itself).
The second paper's forms, ``y = a x + b`` (eq. 14) with the separate vertical form ``x = c``
(eq. 15), are singular at the switch between them: ``a`` and ``b`` grow without bound as a line
turns towards vertical. Both are available here, with conversions.

A pose ``x = (px, py, theta)`` is the filter's pose; the sensor sits at ``offset = (forward,
left)`` from it in the pose's frame, with its axis along the heading. The second paper's laser is
``Ls = 0.18`` m behind the reference point: ``offset = (-Ls, 0)``. A beam at angle ``phi`` (in the
sensor frame, left positive) leaves the sensor in the world direction ``theta + phi``.

The per-beam ranges (the paper's measurement, eq. 14-17) are pure JAX functions of the pose, the
beam angle and the feature, differentiable, and return the range with a mask of the beams that
hit; a miss has range ``inf`` (never NaN). The leading shapes of the pose, the beam angle and
the feature broadcast against each other (a whole scan against one line: a pose ``(3,)``, beam
angles ``(B,)`` and a line ``(2,)``), as do those of the line and the pose of the frame transforms.

The measurement plug-ins:

- :class:`LineSegment`: landmark a world line ``(rho, alpha)``, detection the line of a segment
  in the sensor frame ``(rho_s, alpha_s)`` as the front end's line fit reports it.
- :class:`Circle`: landmark a circle ``(xc, yc, R)`` (an arc, a round pillar), detection the
  range and bearing of its centre from the sensor and its radius, as the front end's circle fit
  gives them.
"""

from __future__ import annotations

import math
from typing import ClassVar, NamedTuple, Union

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from nanoslam_jax.lib._angles import wrap_angle
from nanoslam_jax.models._measurement import AbstractMeasurementModel
from nanoslam_jax.models._motion import _f

__all__ = [
    "SlopeIntercept",
    "normalize_line",
    "line_from_slope_intercept",
    "line_from_vertical",
    "line_through",
    "slope_intercept_from_line",
    "sensor_pose",
    "line_to_sensor",
    "line_to_world",
    "beam_range_line",
    "beam_range_slope_intercept",
    "beam_range_vertical",
    "beam_range_circle",
    "LineSegment",
    "Circle",
]

#: A sensor offset ``(forward, left)`` (m), or None for none.
_Offset = Union[Float[ArrayLike, "2"], tuple[float, float], None]

#: ``|cos|`` of the angle between a beam and a line's normal below which they count as parallel.
_PARALLEL = 1e-12


def _split(line: Float[ArrayLike, "*n 2"]) -> tuple[Array, Array]:
    line = jnp.asarray(line, dtype=float)
    return line[..., 0], line[..., 1]


def normalize_line(line: Float[ArrayLike, "*n 2"]) -> Float[Array, "*n 2"]:
    """The same lines with ``rho >= 0`` and ``alpha`` wrapped to (-pi, pi].

    Args:
        line: lines ``(rho, alpha)``; ``rho`` of any sign (``(-rho, alpha)`` is the line
            ``(rho, alpha + pi)``).
    """
    rho, alpha = _split(line)
    flip = rho < 0
    return jnp.stack([jnp.abs(rho), wrap_angle(jnp.where(flip, alpha + jnp.pi, alpha))], -1)


def line_from_slope_intercept(a: Float[ArrayLike, "*n"], b: Float[ArrayLike, "*n"]) -> Float[Array, "*n 2"]:
    """The normal form of the lines ``y = a x + b`` (the paper's eq. 14).

    Args:
        a: slopes.
        b: intercepts on the y axis (m).

    Returns:
        ``(rho, alpha)``, ``rho >= 0``. A line through the origin (``b = 0``) gets the normal
        ``(-a, 1) / sqrt(1 + a^2)`` (pointing to positive y).
    """
    a, b = jnp.asarray(a, dtype=float), jnp.asarray(b, dtype=float)
    norm = jnp.sqrt(1.0 + jnp.square(a))
    return normalize_line(jnp.stack([b / norm, jnp.arctan2(jnp.ones_like(a), -a)], -1))


def line_from_vertical(c: Float[ArrayLike, "*n"]) -> Float[Array, "*n 2"]:
    """The normal form of the vertical lines ``x = c`` (the paper's eq. 15).

    Args:
        c: where the lines cross the x axis (m).

    Returns:
        ``(|c|, 0)`` for ``c >= 0``, ``(|c|, pi)`` for ``c < 0``.
    """
    c = jnp.asarray(c, dtype=float)
    return normalize_line(jnp.stack([c, jnp.zeros_like(c)], -1))


def line_through(p0: Float[ArrayLike, "*n 2"], p1: Float[ArrayLike, "*n 2"]) -> Float[Array, "*n 2"]:
    """The normal form of the lines through two points each (a segment's ends).

    Args:
        p0: first points ``(x, y)`` (m).
        p1: second points, distinct from the first.

    Returns:
        ``(rho, alpha)``, normalised (``rho >= 0``).
    """
    p0, p1 = jnp.asarray(p0, dtype=float), jnp.asarray(p1, dtype=float)
    d = p1 - p0
    length = jnp.hypot(d[..., 0], d[..., 1])
    n_x, n_y = -d[..., 1] / length, d[..., 0] / length
    rho = n_x * p0[..., 0] + n_y * p0[..., 1]
    return normalize_line(jnp.stack([rho, jnp.arctan2(n_y, n_x)], -1))


class SlopeIntercept(NamedTuple):
    """Lines in the paper's forms: ``y = a x + b`` where ``vertical`` is False, ``x = c`` where it
    is True (the other form's fields are 0 there).

    Attributes:
        a: slope.
        b: intercept on the y axis (m).
        c: intercept on the x axis of a vertical line (m).
        vertical: which lines take the vertical form.
    """

    a: Float[Array, "*n"]
    b: Float[Array, "*n"]
    c: Float[Array, "*n"]
    vertical: Bool[Array, "*n"]


def slope_intercept_from_line(line: Float[ArrayLike, "*n 2"], max_slope: float = 1e6) -> SlopeIntercept:
    """The paper's forms of lines in normal form.

    Args:
        line: lines ``(rho, alpha)`` (``rho`` of any sign).
        max_slope: lines steeper than this (``|a| > max_slope``) take the vertical form ``x = c``.

    Returns:
        :class:`SlopeIntercept`: ``a = -cos(alpha) / sin(alpha)``, ``b = rho / sin(alpha)``, or
        ``c = rho / cos(alpha)`` for a vertical line.
    """
    rho, alpha = _split(line)
    c_a, s_a = jnp.cos(alpha), jnp.sin(alpha)
    vertical = jnp.abs(c_a) > max_slope * jnp.abs(s_a)
    s_safe = jnp.where(vertical, 1.0, s_a)
    c_safe = jnp.where(vertical, c_a, 1.0)
    zero = jnp.zeros_like(rho)
    return SlopeIntercept(
        a=jnp.where(vertical, zero, -c_a / s_safe),
        b=jnp.where(vertical, zero, rho / s_safe),
        c=jnp.where(vertical, rho / c_safe, zero),
        vertical=vertical,
    )


def sensor_pose(pose: Float[ArrayLike, "*n 3"], offset: _Offset = None) -> Float[Array, "*n 3"]:
    """The sensor's pose in the world: the pose moved by ``offset`` in its own frame.

    Args:
        pose: ``(px, py, theta)`` of the filter's reference point.
        offset: the sensor's position ``(forward, left)`` in the pose's frame (m; None: 0); the
            paper's ``(-Ls, 0)``.
    """
    pose = jnp.asarray(pose, dtype=float)
    off = jnp.zeros(2) if offset is None else jnp.asarray(offset, dtype=float)
    c, s = jnp.cos(pose[..., 2]), jnp.sin(pose[..., 2])
    return jnp.stack([pose[..., 0] + c * off[0] - s * off[1], pose[..., 1] + s * off[0] + c * off[1], pose[..., 2]], -1)


def line_to_sensor(
    line: Float[ArrayLike, "*f 2"], pose: Float[ArrayLike, "*p 3"], offset: _Offset = None
) -> Float[Array, "*n 2"]:
    """A world line in the sensor's frame.

    With the sensor at ``s`` heading ``theta``: ``rho_s = rho - n(alpha) . s``, ``alpha_s = alpha -
    theta``, then normalised (``rho_s >= 0``: the normal points from the sensor to the line).

    Args:
        line: world lines ``(rho, alpha)`` (``rho`` of any sign).
        pose: the filter's pose ``(px, py, theta)``.
        offset: the sensor's position in the pose's frame (see :func:`sensor_pose`).

    Returns:
        ``(rho_s, alpha_s)``: the line's distance from the sensor and the bearing of its foot
        point (the nearest point to the sensor) in the sensor's frame.
    """
    rho, alpha = _split(line)
    s = sensor_pose(pose, offset)
    rho_s = rho - jnp.cos(alpha) * s[..., 0] - jnp.sin(alpha) * s[..., 1]
    return normalize_line(jnp.stack([rho_s, alpha - s[..., 2]], -1))


def line_to_world(
    line_s: Float[ArrayLike, "*f 2"], pose: Float[ArrayLike, "*p 3"], offset: _Offset = None
) -> Float[Array, "*n 2"]:
    """A line in the sensor's frame in the world: the inverse of :func:`line_to_sensor`.

    Args:
        line_s: lines ``(rho_s, alpha_s)`` in the sensor's frame.
        pose: the filter's pose ``(px, py, theta)``.
        offset: the sensor's position in the pose's frame.

    Returns:
        World lines ``(rho, alpha)``, normalised.
    """
    rho_s, alpha_s = _split(line_s)
    s = sensor_pose(pose, offset)
    alpha = alpha_s + s[..., 2]
    rho = rho_s + jnp.cos(alpha) * s[..., 0] + jnp.sin(alpha) * s[..., 1]
    return normalize_line(jnp.stack([rho, alpha], -1))


def _beam(pose, phi, offset):
    """The sensor's position and the beam's world direction."""
    s = sensor_pose(pose, offset)
    psi = s[..., 2] + jnp.asarray(phi, dtype=float)
    return s[..., 0], s[..., 1], jnp.cos(psi), jnp.sin(psi)


def _ray_fraction(num: Array, den: Array) -> tuple[Array, Bool[Array, "*n"]]:
    """``num / den`` where the beam is not parallel and the hit is ahead; ``inf`` elsewhere."""
    ok = jnp.abs(den) > _PARALLEL
    r = num / jnp.where(ok, den, 1.0)
    hit = ok & (r > 0)
    return jnp.where(hit, r, jnp.inf), hit


def beam_range_line(
    pose: Float[ArrayLike, "*p 3"], phi: Float[ArrayLike, "*b"], line: Float[ArrayLike, "*f 2"], offset: _Offset = None
) -> tuple[Float[Array, "*n"], Bool[Array, "*n"]]:
    """The range along a beam to a line in normal form.

    With the sensor at ``s`` and the beam's direction ``d`` (world angle ``theta + phi``):
    ``r = (rho - n . s) / (n . d)``, ``n = (cos alpha, sin alpha)``. This is eq. 14-15 of the paper
    written in the normal form: one formula for every line.

    Args:
        pose: the filter's pose ``(px, py, theta)``.
        phi: the beam's angle in the sensor frame (rad).
        line: the line ``(rho, alpha)`` in the world (``rho`` of any sign).
        offset: the sensor's position in the pose's frame (the paper's ``(-Ls, 0)``).

    Returns:
        ``(r, hit)``: the range (m; ``inf`` where the beam misses) and whether the beam meets the
        line ahead of the sensor (not parallel, ``r > 0``).
    """
    rho, alpha = _split(line)
    sx, sy, dx, dy = _beam(pose, phi, offset)
    n_x, n_y = jnp.cos(alpha), jnp.sin(alpha)
    return _ray_fraction(rho - n_x * sx - n_y * sy, n_x * dx + n_y * dy)


def beam_range_slope_intercept(
    pose: Float[ArrayLike, "*p 3"],
    phi: Float[ArrayLike, "*b"],
    a: Float[ArrayLike, "*f"],
    b: Float[ArrayLike, "*f"],
    offset: _Offset = None,
) -> tuple[Float[Array, "*n"], Bool[Array, "*n"]]:
    """The range along a beam to the line ``y = a x + b``: the paper's eq. 14,
    ``r = (a s_x - s_y + b) / (sin(theta + phi) - a cos(theta + phi))``, with the sensor at
    ``s = (x - Ls cos theta, y - Ls sin theta)`` for ``offset = (-Ls, 0)``.

    Args:
        pose: the filter's pose ``(px, py, theta)``.
        phi: the beam's angle in the sensor frame (rad).
        a: the line's slope.
        b: its intercept (m).
        offset: the sensor's position in the pose's frame.

    Returns:
        ``(r, hit)`` as :func:`beam_range_line`.
    """
    a, b = jnp.asarray(a, dtype=float), jnp.asarray(b, dtype=float)
    sx, sy, dx, dy = _beam(pose, phi, offset)
    return _ray_fraction(a * sx - sy + b, dy - a * dx)


def beam_range_vertical(
    pose: Float[ArrayLike, "*p 3"], phi: Float[ArrayLike, "*b"], c: Float[ArrayLike, "*f"], offset: _Offset = None
) -> tuple[Float[Array, "*n"], Bool[Array, "*n"]]:
    """The range along a beam to the vertical line ``x = c``: the paper's eq. 15,
    ``r = (c - s_x) / cos(theta + phi)``.

    Args:
        pose: the filter's pose ``(px, py, theta)``.
        phi: the beam's angle in the sensor frame (rad).
        c: where the line crosses the x axis (m).
        offset: the sensor's position in the pose's frame.

    Returns:
        ``(r, hit)`` as :func:`beam_range_line`.
    """
    sx, _, dx, _ = _beam(pose, phi, offset)
    return _ray_fraction(jnp.asarray(c, dtype=float) - sx, dx)


def beam_range_circle(
    pose: Float[ArrayLike, "*p 3"],
    phi: Float[ArrayLike, "*b"],
    circle: Float[ArrayLike, "*f 3"],
    offset: _Offset = None,
) -> tuple[Float[Array, "*n"], Bool[Array, "*n"]]:
    """The range along a beam to a circle: its nearest intersection ahead of the sensor, the
    paper's eq. 16-17, ``r = d_S cos(theta_j) -+ sqrt(d_S^2 cos^2(theta_j) - (d_S^2 - R^2))`` with
    ``d_S`` the distance from the sensor to the centre and ``theta_j`` the angle between the beam
    and the direction to the centre.

    The near root (minus) is the range from outside the circle; from inside (``d_S < R``) only
    the far root (plus) lies ahead.

    Args:
        pose: the filter's pose ``(px, py, theta)``.
        phi: the beam's angle in the sensor frame (rad).
        circle: ``(xc, yc, R)``, centre and radius (m).
        offset: the sensor's position in the pose's frame.

    Returns:
        ``(r, hit)``: the range (``inf`` where the beam misses) and whether the beam meets the
        circle ahead of the sensor.
    """
    circle = jnp.asarray(circle, dtype=float)
    sx, sy, dx, dy = _beam(pose, phi, offset)
    wx, wy = circle[..., 0] - sx, circle[..., 1] - sy
    along = wx * dx + wy * dy  # d_S cos(theta_j)
    disc = jnp.square(along) - (jnp.square(wx) + jnp.square(wy) - jnp.square(circle[..., 2]))
    meets = disc > 0
    root = jnp.sqrt(jnp.where(meets, disc, 1.0))
    near, far = along - root, along + root
    r = jnp.where(near > 0, near, far)
    hit = meets & (r > 0)
    return jnp.where(hit, r, jnp.inf), hit


class _SensorFeature(AbstractMeasurementModel):
    """A feature seen by a sensor offset from the pose, whose detection starts with the feature's
    distance and bearing from the sensor (``z[0]``, ``z[1]``): the sensor's range and field of view
    and its offset, shared by :class:`LineSegment` and :class:`Circle`.

    :meth:`visible`: ``z[0]`` and ``z[1]`` inside the range and field of view shrunk by the margins.
    """

    min_range: Float[Array, ""] = eqx.field(default=0.0, converter=_f)
    max_range: Float[Array, ""] = eqx.field(default=np.inf, converter=_f)
    half_fov: Float[Array, ""] = eqx.field(default=math.pi, converter=_f)
    view_margin: Float[Array, ""] = eqx.field(default=0.0, converter=_f)
    view_margin_angle: Float[Array, ""] = eqx.field(default=0.0, converter=_f)
    sensor_x: Float[Array, ""] = eqx.field(default=0.0, converter=_f)
    sensor_y: Float[Array, ""] = eqx.field(default=0.0, converter=_f)

    @property
    def offset(self) -> Float[Array, "2"]:
        """The sensor's position ``(forward, left)`` in the pose's frame."""
        return jnp.stack([jnp.asarray(self.sensor_x), jnp.asarray(self.sensor_y)])

    def visible(self, x, m):
        z = self.h(x, m)
        return (
            (z[0] > self.min_range + self.view_margin)
            & (z[0] < self.max_range - self.view_margin)
            & (jnp.abs(z[1]) < self.half_fov - self.view_margin_angle)
        )


class LineSegment(_SensorFeature):
    """A line landmark seen as a segment: landmark the world line ``m = (rho, alpha)``, detection
    the segment's line in the sensor's frame ``z = (rho_s, alpha_s)`` (:func:`line_to_sensor`), as
    the front end's total least squares line fit reports it (``Lines.rho``, ``Lines.alpha``).

    :meth:`landmark_from` is :func:`line_to_world`. The innovation wraps ``alpha_s``. The filter's
    local window searches the lines by their perpendicular distance from the particle
    (:meth:`window_distance2`).

    :meth:`visible`: the line's foot point, its nearest point to the sensor (range ``rho_s``,
    bearing ``alpha_s``), lies inside the sensor's range and field of view shrunk by the margins.
    The landmark is an infinite line and keeps no extent; the foot point is where a wall is
    nearest and best seen, and lies on the wall for the walls around a sensor inside a convex
    room. A line whose segment stops short of its foot point (a wall beside an opening) is
    counted visible where it may not be seen: raise the miss limits of landmark management or
    switch it off (``map.manage``) for such maps.

    The noise is diagonal: a segment's fitted ``(rho_s, alpha_s)`` are uncorrelated when the
    segment's centre is its foot point and correlated otherwise, which one ``R`` for every
    detection cannot express.

    Attributes:
        sigma_rho: noise of ``rho_s`` (m).
        sigma_alpha: noise of ``alpha_s`` (rad).
        min_range: the sensor's minimum range (m).
        max_range: the sensor's range (m).
        half_fov: half the field of view (rad).
        view_margin: range margin of :meth:`visible` (m).
        view_margin_angle: bearing margin of :meth:`visible` (rad).
        sensor_x: the sensor's position forward of the pose's reference point (m); 0 when the
            pose is the sensor's (the ``unicycle`` and ``ackermann`` models).
        sensor_y: the sensor's position to the left of the reference point (m).
    """

    angles: ClassVar[tuple[int, ...]] = (1,)

    sigma_rho: Float[Array, ""] = eqx.field(default=0.02, converter=_f)
    sigma_alpha: Float[Array, ""] = eqx.field(default=math.radians(1.0), converter=_f)

    def h(self, x, m, aux=None):
        return line_to_sensor(m, x, self.offset)

    def landmark_from(self, x, z, aux=None):
        return line_to_world(z, x, self.offset)

    def window_distance2(self, position, m):
        """Squared perpendicular distance from ``position`` to each line ``(rho, alpha)``."""
        return jnp.square(m[:, 0] - jnp.cos(m[:, 1]) * position[0] - jnp.sin(m[:, 1]) * position[1])

    def noise_cov(self):
        return jnp.diag(jnp.stack([jnp.square(self.sigma_rho), jnp.square(self.sigma_alpha)]))


class Circle(_SensorFeature):
    """A circle landmark (an arc of a wall, a round pillar): landmark ``m = (xc, yc, R)``,
    detection the range and bearing of the centre from the sensor and the radius, ``z = (r, b,
    R)``; the bearing relative to the sensor's axis, wrapped. The front end's circle fit gives
    ``r = hypot(cx, cy)``, ``b = atan2(cy, cx)``, ``R = radius``.

    :meth:`visible`: the centre lies inside the sensor's range and field of view shrunk by the
    margins.

    Attributes:
        sigma_r: noise of the centre's range (m).
        sigma_beta: noise of its bearing (rad).
        sigma_radius: noise of the radius (m).
        min_range: the sensor's minimum range (m).
        max_range: the sensor's range (m).
        half_fov: half the field of view (rad).
        view_margin: range margin of :meth:`visible` (m).
        view_margin_angle: bearing margin of :meth:`visible` (rad).
        sensor_x: the sensor's position forward of the pose's reference point (m).
        sensor_y: the sensor's position to the left of the reference point (m).
    """

    landmark_dim: ClassVar[int] = 3
    measurement_dim: ClassVar[int] = 3
    angles: ClassVar[tuple[int, ...]] = (1,)

    sigma_r: Float[Array, ""] = eqx.field(default=0.02, converter=_f)
    sigma_beta: Float[Array, ""] = eqx.field(default=math.radians(1.0), converter=_f)
    sigma_radius: Float[Array, ""] = eqx.field(default=0.02, converter=_f)

    def h(self, x, m, aux=None):
        s = sensor_pose(x, self.offset)
        dx, dy = m[0] - s[0], m[1] - s[1]
        r = jnp.sqrt(jnp.maximum(jnp.square(dx) + jnp.square(dy), 1e-24))
        return jnp.stack([r, wrap_angle(jnp.arctan2(dy, dx) - s[2]), m[2]])

    def landmark_from(self, x, z, aux=None):
        s = sensor_pose(x, self.offset)
        a = s[2] + z[1]
        return jnp.stack([s[0] + z[0] * jnp.cos(a), s[1] + z[0] * jnp.sin(a), z[2]])

    def noise_cov(self):
        return jnp.diag(
            jnp.stack([jnp.square(self.sigma_r), jnp.square(self.sigma_beta), jnp.square(self.sigma_radius)])
        )
