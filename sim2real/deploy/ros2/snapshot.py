"""The control thread's hand-off to the ROS 2 node: one tick's state, triple-buffered.

The control thread fills the back buffer (a few array copies into preallocated arrays) and swaps
it with the middle one under a lock held for two assignments; the node's thread swaps the middle
one with its front buffer when it wakes and publishes from that. Neither ever waits for the other
to publish or to fill: a node that falls behind skips ticks (counted, :attr:`TripleBuffer.skipped`),
it never delays one.
"""

from __future__ import annotations

import threading

import numpy as np


class TickSnapshot:
    """One tick of one robot, as the node publishes it.

    Attributes:
        tick: The runtime's tick count. time: s, the runtime's clock. wall_ns: ns, the
            system clock when the tick ended (the messages' stamp).
        q: (n,) rad, estimated joint positions. dq: (n,) rad/s, estimated joint velocities.
        command: (n,) the command written (units of the control mode).
        winding_temperature: (n,) degC, as the drives last reported it.
        effort_scale: (n,) the thermal derating of each joint's effort limit (1: none).
        mode, cause: The state machine's mode and cause (index into ``FAULT_CAUSES``, -1 none).
        Floating base only (else None): orientation (4,) ``[w, x, y, z]``; angular_velocity (3,)
        rad/s base frame; linear_velocity (3,) m/s base frame; acceleration (3,) m/s^2, the
        accelerometer's last reading (NaN when none arrived); position (3,) m, the base's
        dead-reckoned position in the odometry frame (the estimated world velocity integrated).
    """

    def __init__(self, n: int, legged: bool):
        self.tick, self.time, self.wall_ns, self.mode, self.cause = 0, 0.0, 0, 0, -1
        self.q, self.dq, self.command = np.zeros(n), np.zeros(n), np.zeros(n)
        self.winding_temperature, self.effort_scale = np.zeros(n), np.ones(n)
        self.orientation = np.array([1.0, 0.0, 0.0, 0.0]) if legged else None
        self.angular_velocity = np.zeros(3) if legged else None
        self.linear_velocity = np.zeros(3) if legged else None
        self.acceleration = np.zeros(3) if legged else None
        self.position = np.zeros(3) if legged else None


class TripleBuffer:
    """Three :class:`TickSnapshot`: the writer's back, the shared middle, the reader's front.

    Attributes:
        back: The writer fills it, then calls :meth:`publish`.
        front: The reader's, after :meth:`take` returned True.
        written, taken, skipped: Snapshots published, taken, and published but overwritten
            before the reader took them.
    """

    def __init__(self, n: int, legged: bool):
        self.back, self._middle, self.front = (TickSnapshot(n, legged) for _ in range(3))
        self._fresh = False
        self._lock = threading.Lock()
        self.written = self.taken = self.skipped = 0

    def publish(self) -> None:
        """The writer's back buffer becomes the newest snapshot."""
        with self._lock:
            self.back, self._middle = self._middle, self.back
            self.skipped += self._fresh
            self._fresh = True
        self.written += 1

    def take(self) -> bool:
        """The newest snapshot into :attr:`front`; False (front unchanged) when none is new."""
        with self._lock:
            if not self._fresh:
                return False
            self.front, self._middle = self._middle, self.front
            self._fresh = False
        self.taken += 1
        return True
