"""Where the base went during a clip and after it, against the clip's own root path.

A clip carries its floating base's path (:attr:`MotionClip.root_pos
<sim2real.deploy.tasks.motion.clip.MotionClip.root_pos>`, ``root_quat``): a dance that stays on
its spot has a root path that ends near where it began; one that travels has its own end point.
:class:`ClipTravel` turns that path onto the robot at each clip's start (its planar start at the
base's position, its first heading onto the base's heading: the pelvis' yaw, as the clip's root
is the pelvis) and follows the base (the plant's truth in simulation; on hardware, the base
estimate's world velocity integrated and its yaw, which drift) tick by tick:

- during the clip: the base's planar travel and heading change against the clip's root path's
  over the same time, and at the clip's end how far the base is from where the turned root path
  ends (``clip_end_offset_m``);
- after the clip (a hold judged, or the policy handed over to): the time, the travel from where
  the clip ended, the farthest it got, the heading change;
- now: how far the base is from the root path's point at the clip time reached
  (``end_offset_m``; its end once the clip is over).

A base more than :data:`OFF_PATH_M` from the root path's end when the run ends, or that travelled
more than :data:`AFTER_CLIP_M` after the clip, left its spot: ``deploy-run`` calls it a finding
and exits 5 (:mod:`sim2real.deploy.cli.deploy_run`).
"""

from __future__ import annotations

import math

import numpy as np

from sim2real.deploy.core.attitude import yaw_of

#: m a clip run's base may end from where the clip's root path ends (the bound: the G1's
#: dances end within 0.5 m of their clip's end in rl_sar's own loop, which hands the robot to
#: its locomotion policy at the clip's end, ``fsm_g1.hpp``).
OFF_PATH_M = 0.5
#: m the base may travel after the clip, holding or under the policy handed over to (the same
#: bound: standing still is the point of what follows a dance).
AFTER_CLIP_M = 0.5


def _wrap(a):
    return np.angle(np.exp(1j * np.asarray(a)))


class ClipTravel:
    """The base's travel of ``envs`` robots against the clip of ``clock`` (module docstring).

    Args:
        clock: The :class:`~sim2real.deploy.tasks.motion.clock.MotionClock` (its clip's root
            path and ``frame``).
        envs: Batch size.

    Attributes (the state, :meth:`state_dict`):
        pos: (envs, 2) m, the base's planar position at the last update. yaw: (envs,) rad, its
            heading, unwrapped (a turn of 720 deg reads 4 pi). start: (envs, 3) ``x, y, yaw``
            where this play's clip started (NaN: none). turn: (envs,) rad, the clip's frame to
            the world's (the base's heading at the start less the clip root's first).
        end: (envs, 3) ``x, y, yaw`` where this play's clip ended (NaN: not yet).
        after_max: (envs,) m, the farthest from ``end`` since. after_s: (envs,) s after the end.
        reached: (envs,) s of the clip reached in this play. dead_reckoned: (envs, 2) m, without
        a truth: the base estimate's world velocity summed.
    """

    FIELDS = (
        "pos", "yaw", "start", "turn", "end", "after_max", "after_s", "reached", "dead_reckoned",
    )  # fmt: skip

    def __init__(self, clock, envs: int):
        clip = clock.clip
        self.clock, self.envs = clock, envs
        self.root_xy = np.asarray(clip.root_pos[:, :2], dtype=float)
        self.root_yaw = np.unwrap(yaw_of(clip.root_quat))
        self.pos = np.zeros((envs, 2))
        self.yaw = np.zeros(envs)
        self.start = np.full((envs, 3), np.nan)
        self.turn = np.zeros(envs)
        self.end = np.full((envs, 3), np.nan)
        self.after_max = np.zeros(envs)
        self.after_s = np.zeros(envs)
        self.reached = np.zeros(envs)
        self.dead_reckoned = np.zeros((envs, 2))

    def _root(self, t: float) -> tuple[np.ndarray, float]:
        """The clip's root ``(xy (2,) m, unwrapped yaw rad)`` at clip time ``t`` s."""
        i0, i1, b = self.clock.frame(t)
        xy = self.root_xy[i0] * (1.0 - b) + self.root_xy[i1] * b
        return xy, float(self.root_yaw[i0] * (1.0 - b) + self.root_yaw[i1] * b)

    def expected(self, e: int, t: float) -> np.ndarray:
        """(2,) m: env ``e``'s clip root path at clip time ``t``, turned onto where and how the
        base stood at this play's start."""
        c, s = math.cos(self.turn[e]), math.sin(self.turn[e])
        d = self._root(t)[0] - self.root_xy[0]
        return self.start[e, :2] + np.array([c * d[0] - s * d[1], s * d[0] + c * d[1]])

    def update(self, pos: np.ndarray, yaw: np.ndarray, dt: float) -> None:
        """The base now: planar position (envs, 2) m and heading (envs,) rad (wrapped)."""
        self.yaw += _wrap(yaw - _wrap(self.yaw))  # from 0: the first update sets it
        self.pos[:] = pos
        over = ~np.isnan(self.end[:, 0])
        if over.any():
            self.after_s[over] += dt
            far = np.linalg.norm(self.pos[over] - self.end[over, :2], axis=1)
            self.after_max[over] = np.maximum(self.after_max[over], far)

    def locate(self, truth: np.ndarray | None, base, dt: float) -> None:
        """:meth:`update` from the plant's true base state ``truth`` (envs, 13: position,
        quaternion ``w x y z``, ...), or without one from the base estimate ``base`` (a
        :class:`~sim2real.deploy.core.state.BaseState`: its world velocity summed over ``dt`` s,
        its yaw; both drift)."""
        if truth is not None:
            self.update(truth[:, :2], yaw_of(truth[:, 3:7]), dt)
            return
        self.dead_reckoned += base.linear_velocity_world[:, :2] * dt
        self.update(self.dead_reckoned, yaw_of(base.orientation), dt)

    def summary(self, truth: bool) -> dict:
        """Every env's :meth:`figures` (``envs``), the bounds (``off_path_m``,
        ``after_clip_m``), what judged them (``judged_on``: the plant's ``truth`` or the
        estimate) and ``off_path``: the envs beyond a bound."""
        envs = [self.figures(e) for e in range(self.envs)]
        return {
            "envs": envs,
            "off_path_m": OFF_PATH_M,
            "after_clip_m": AFTER_CLIP_M,
            "judged_on": (
                "plant truth" if truth
                else "estimate (its world velocity summed, its yaw: both drift)"
            ),
            "off_path": [e for e, f in enumerate(envs) if f is not None and f["off_path"]],
        }  # fmt: skip

    def begin(self, envs: np.ndarray) -> None:
        """A clip starts for the envs of ``envs`` (bool): its root path is laid from here."""
        e = np.flatnonzero(envs)
        self.start[e, :2] = self.pos[e]
        self.start[e, 2] = self.yaw[e]
        self.turn[e] = self.yaw[e] - self.root_yaw[0]
        self.end[e] = np.nan
        self.after_max[e] = 0.0
        self.after_s[e] = 0.0
        self.reached[e] = 0.0

    def reach(self, clip_time: np.ndarray, playing: np.ndarray) -> None:
        """The clip time (envs,) s the playing envs (bool) reached; the envs whose clip reached
        its end now are noted ended here."""
        length = self.clock.length
        e = np.flatnonzero(playing & ~np.isnan(self.start[:, 0]))
        self.reached[e] = np.maximum(self.reached[e], np.minimum(clip_time[e], length))
        done = e[(self.reached[e] >= length - 1e-9) & np.isnan(self.end[e, 0])]
        self.end[done, :2] = self.pos[done]
        self.end[done, 2] = self.yaw[done]

    def figures(self, e: int) -> dict | None:
        """Env ``e``'s play (None before a clip started), distances m, turns deg:
        ``clip_root_travel_m`` and ``clip_turn_deg`` (the clip's root path to the time reached),
        ``base_travel_m`` and ``base_turn_deg`` (the base's over the same time),
        ``clip_end_offset_m`` (at the clip's end from the root path's end; None before),
        ``after_clip_s``, ``after_clip_travel_m`` (now from where the clip ended),
        ``after_clip_max_m``, ``after_clip_turn_deg`` (None before the clip's end), and
        ``end_offset_m`` (now from the root path at the time reached), ``off_path`` (over
        :data:`OFF_PATH_M` or :data:`AFTER_CLIP_M`)."""
        if np.isnan(self.start[e, 0]):
            return None
        t = float(self.reached[e])
        root_xy, root_yaw = self._root(t)
        ended = not np.isnan(self.end[e, 0])
        during = self.end[e] if ended else np.array([*self.pos[e], self.yaw[e]])
        end_offset = float(np.linalg.norm(self.pos[e] - self.expected(e, t)))
        out = {
            "clip_s": t,
            "clip_root_travel_m": float(np.linalg.norm(root_xy - self.root_xy[0])),
            "clip_turn_deg": math.degrees(root_yaw - self.root_yaw[0]),
            "base_travel_m": float(np.linalg.norm(during[:2] - self.start[e, :2])),
            "base_turn_deg": math.degrees(during[2] - self.start[e, 2]),
            "clip_end_offset_m": (
                float(np.linalg.norm(self.end[e, :2] - self.expected(e, t))) if ended else None
            ),
            "after_clip_s": float(self.after_s[e]) if ended else None,
            "after_clip_travel_m": (
                float(np.linalg.norm(self.pos[e] - self.end[e, :2])) if ended else None
            ),
            "after_clip_max_m": float(self.after_max[e]) if ended else None,
            "after_clip_turn_deg": math.degrees(self.yaw[e] - self.end[e, 2]) if ended else None,
            "end_offset_m": end_offset,
        }
        out["off_path"] = end_offset > OFF_PATH_M or (
            ended and out["after_clip_max_m"] > AFTER_CLIP_M
        )
        return out

    def state_dict(self, env: int | None = None) -> dict:
        """The attributes of :data:`FIELDS` (one env's: ``env``)."""
        from sim2real.deploy.core.stateful import take

        return take({k: getattr(self, k) for k in self.FIELDS}, env)

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict`; a state that does not fit changes nothing.

        Raises:
            StateDictError: a field missing or shaped otherwise (named).
        """
        from sim2real.deploy.core.stateful import put

        put({k: getattr(self, k) for k in self.FIELDS}, state, env)
