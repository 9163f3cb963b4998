"""The fake UR's motion profiles: straight segments at the commanded speed under the commanded acceleration.

Part of :mod:`sim_fakes.fake_ur` (its docstring describes the fake as a whole).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from sim_fakes.fake_ur.kinematics import ROT_RADIUS_M, pose_to_X, rotation, rotvec

FloatArray = NDArray[np.float64]


@dataclass
class Segment:
    """A straight tool move from (p0, R0) to (p1, R1); ``length`` in the path metric (m), speed m/s, accel m/s²."""

    p0: FloatArray
    p1: FloatArray
    R0: FloatArray
    w: FloatArray  # rotation vector of R0ᵀ R1, so R(f) = R0 exp(f w)
    length: float
    speed: float
    accel: float
    blend: float
    waypoint: int
    stop: bool = True  # the tool stops at the end of this segment
    to_stop: float = 0.0  # path length from this segment's end to the next stop, m
    v_exit: float = 0.0  # the speed this segment may end with (a slower next segment lowers it), m/s

    def pose_at(self, s: float) -> tuple[FloatArray, FloatArray]:
        f = 1.0 if self.length <= 0.0 else min(1.0, max(0.0, s / self.length))
        return self.p0 + f * (self.p1 - self.p0), self.R0 @ rotation(f * self.w)


@dataclass(frozen=True)
class Waypoint:
    """A commanded tool pose (UR pose vector) with its speed (m/s), acceleration (m/s²) and blend radius (m)."""

    pose: tuple[float, ...]
    speed: float
    accel: float
    blend: float


def build_segments(p: FloatArray, R: FloatArray, waypoints: Sequence[Waypoint]) -> list[Segment]:
    segments: list[Segment] = []
    for i, wp in enumerate(waypoints):
        X = pose_to_X(wp.pose)
        p1, R1 = X[:3, 3], X[:3, :3]
        w = rotvec(R.T @ R1)
        length = max(float(np.linalg.norm(p1 - p)), ROT_RADIUS_M * float(np.linalg.norm(w)))
        segments.append(Segment(p, p1, R, w, length, wp.speed, wp.accel, wp.blend, i))
        p, R = p1, R1
    # backward pass: where the next stop is, and the speed each segment may end with
    for i in range(len(segments) - 1, -1, -1):
        seg = segments[i]
        seg.stop = i == len(segments) - 1 or seg.blend <= 0.0
        if seg.stop:
            seg.to_stop, seg.v_exit = 0.0, 0.0
        else:
            nxt = segments[i + 1]
            seg.to_stop = nxt.length + nxt.to_stop
            seg.v_exit = min(seg.speed, nxt.speed)
    return segments


def _braking_speed(u: float, v_end: float, distance: float, accel: float, dt: float) -> float:
    """The fastest speed to reach after ``dt`` from speed ``u`` that still brakes to ``v_end`` within ``distance``.

    Solves u_new² = v_end² + 2·a·(distance − (u + u_new)·dt/2): the end of the step lies on the braking curve.
    """
    c = v_end**2 + 2.0 * accel * distance - accel * u * dt
    return 0.5 * (-accel * dt + math.sqrt((accel * dt) ** 2 + 4.0 * c)) if c > 0.0 else 0.0


class Motion:
    """Integrates a list of segments over time; ``on_waypoint(i)`` fires when segment ``i`` is entered."""

    def __init__(self, segments: list[Segment], on_waypoint: Callable[[int], None] | None = None) -> None:
        self.segments = segments
        self.on_waypoint = on_waypoint
        self.on_finished: list[Callable[[str], None]] = []
        self.k = 0
        self.s = 0.0
        self.u = 0.0  # current path speed, m/s
        self.stop_decel: float | None = None
        self.done = not segments
        self.reason = "arrived"
        self._announced = -1

    def request_stop(self, decel_m_s2: float) -> None:
        self.stop_decel = max(decel_m_s2, 1e-3)

    def pose(self) -> tuple[FloatArray, FloatArray]:
        seg = self.segments[min(self.k, len(self.segments) - 1)]
        return seg.pose_at(self.s)

    def _announce(self) -> None:
        if self._announced != self.k and self.on_waypoint is not None and self.k < len(self.segments):
            self._announced = self.k
            self.on_waypoint(self.segments[self.k].waypoint)

    def _finish_segment(self) -> bool:
        """Move past the current segment's end; True when the whole motion is done."""
        seg = self.segments[self.k]
        self.s = seg.length
        if self.k == len(self.segments) - 1:
            self.done = True
            self.u = 0.0
            return True
        if seg.stop:
            self.u = 0.0
        self.k += 1
        self.s = 0.0
        self._announce()
        return False

    def step(self, dt: float) -> None:
        if self.done:
            return
        self._announce()
        while self.segments[self.k].length <= 1e-12:
            if self._finish_segment():
                return
        seg = self.segments[self.k]
        if self.stop_decel is not None:
            u_new = max(0.0, self.u - self.stop_decel * dt)
        else:
            a = seg.accel
            remaining = max(seg.length - self.s, 0.0)
            u_new = min(seg.speed, self.u + a * dt, _braking_speed(self.u, 0.0, remaining + seg.to_stop, a, dt))
            if seg.v_exit < seg.speed and not seg.stop:  # slow down for a slower next segment
                u_new = min(u_new, _braking_speed(self.u, seg.v_exit, remaining, a, dt))
            u_new = max(0.0, u_new)
        dist = 0.5 * (self.u + u_new) * dt
        self.u = u_new
        while dist > 0.0 and not self.done:
            seg = self.segments[self.k]
            left = seg.length - self.s
            if dist < left - 1e-12:
                self.s += dist
                dist = 0.0
            else:
                dist -= left
                stop_here = seg.stop
                if self._finish_segment():
                    break
                if stop_here:
                    break
        if self.stop_decel is not None and self.u <= 0.0 and not self.done:
            self.done = True
            self.reason = "stopped"
