"""The motion clock: a clip played on the control ticks, as the stack that trained on it plays it.

rl_sar's ``MotionLoader`` (fan-ziqi/rl_sar ``library/core/motion_loader``) and its G1 fsm
(``fsm_g1.hpp``, ``RLFSMStateRLWholeBodyTrackingDance102``), read here and computed alike:

- time: ``t = ticks x dt x decimation`` since the clip started, the first tick at ``t = 0``,
  clamped to the clip's length ``T / fps`` (``duration_ = num_frames x dt``: one frame longer
  than the last frame's time);
- frame: ``f = clamp(t / length, 0, 1) x (T - 1)``, ``i0 = floor(f)``, ``i1 = min(i0 + 1, T -
  1)``, blend ``f - i0``: joint angles and velocities blended linearly, the root quaternion by
  rl_sar's slerp (:func:`~sim2real.deploy.spec.motion_blocks.slerp`);
- anchor: the torso ``root * Rz(yaw) Rx(roll) Ry(pitch)`` of the clip's waist angles;
- start (``Reset``): ``init = yaw(robot torso) * conj(yaw(clip torso at t = 0))``, the robot's
  torso from its base quaternion and waist angles at that moment; the reference anchor is
  ``init * anchor`` from then on.

After the clip: ``once`` and ``hold`` hold the last frame (rl_sar's fsm then switches to its
locomotion policy), ``loop`` starts it again (keeping its alignment), ``stand`` appends a
transition from the last frame to the home pose over ``stand_s`` s that the policy tracks, then
holds home (holosoma's ``enable_default_pose_append`` / ``default_pose_append_duration_s``,
default 2 s, in ``whole_body_tracking``'s motion command: joint angles and velocities blended
linearly from the last frame to home and zero, the root slerped to the last frame's heading
upright, blend ``s / stand_s``); ``exhibition`` is ``stand`` whose home holds ``rest_s`` s,
then the clip starts again (an exhibition's schedule: clip, rest standing, clip again).
"""

from __future__ import annotations

import math

import numpy as np

from sim2real.deploy.spec.motion_blocks import quat_conj, quat_mul, slerp, torso_quat, yaw_only
from sim2real.deploy.tasks.motion.clip import ClipError, MotionClip

#: What happens at the clip's end (module docstring).
PLAYBACK = ("once", "loop", "hold", "stand", "exhibition")
#: s of the transition to home of ``stand`` (holosoma's default_pose_append_duration_s).
STAND_S = 2.0


class MotionClock:
    """One clip on the control ticks of ``envs`` robots (module docstring).

    Args:
        clip: The clip (its joints named).
        joint_names: The robot's joints, in its order (n): the clip is reordered to them.
        waist: The clip's joints that carry the torso, yaw, roll, pitch (by name).
        envs: Batch size.
        playback: One of :data:`PLAYBACK`.
        home: (n,) rad, the pose ``stand`` ends in (robot order); needed for ``stand``.
        stand_s: s, ``stand``'s transition to home (> 0).
        rest_s: s ``exhibition`` rests at home between plays (>= 0).

    Attributes:
        time: (envs,) s since each env's clip started (NaN: not started).
        init: (envs, 4) the yaw alignment ``w x y z`` of each env's start.
        plays: (envs,) int64, clips started.
        length: s, the clip's (rl_sar's ``duration_``); total: s, with ``stand``'s transition.

    Raises:
        ClipError: a robot joint the clip lacks, a waist joint it lacks (naming the file),
            an unknown playback, ``stand`` without a home pose of n angles or a waist joint
            that is no robot joint, a ``stand_s`` not > 0.
    """

    def __init__(
        self, clip: MotionClip, joint_names, waist, envs: int, playback: str = "once",
        home=None, stand_s: float = STAND_S, rest_s: float = 10.0,
    ):  # fmt: skip
        if playback not in PLAYBACK:
            raise ClipError(
                f"{clip.source}: playback: expected one of {PLAYBACK}, got {playback!r}"
            )
        names = list(clip.joint_names)
        missing = [j for j in list(joint_names) + list(waist) if j not in names]
        if missing:
            raise ClipError(
                f"{clip.source}: joint_names: the robot's joints {missing} are not in the clip "
                f"(its {len(names)} joints: {names})"
            )
        order = [names.index(j) for j in joint_names]
        self.clip, self.playback, self.envs = clip, playback, envs
        self.n = len(order)
        self.pos = np.ascontiguousarray(clip.joint_pos[:, order])
        self.vel = np.ascontiguousarray(clip.joint_vel[:, order])
        self.waist = [names.index(j) for j in waist]
        self.length = clip.frames / clip.fps  # rl_sar's duration_: num_frames x dt
        self.total, self.stand_s, self.home = self.length, float(stand_s), None
        self.rest_s = float(rest_s)
        if not (np.isfinite(self.rest_s) and self.rest_s >= 0.0):
            raise ClipError(f"{clip.source}: rest_s: expected s >= 0, got {rest_s!r}")
        #: (envs,) bool, the envs whose clip started again on the last advance (exhibition)
        self.restarted = np.zeros(envs, dtype=bool)
        if playback in ("stand", "exhibition"):
            self._stand(list(joint_names), waist, home)
        self.time = np.full(envs, np.nan)
        self.init = np.tile([1.0, 0.0, 0.0, 0.0], (envs, 1))
        self.plays = np.zeros(envs, dtype=np.int64)

    def _stand(self, joint_names: list, waist, home) -> None:
        """Check ``stand``'s arguments; keep home and the waist joints' robot indices."""
        where = f"{self.clip.source}: playback 'stand'"
        if home is None or np.shape(home) != (self.n,):
            raise ClipError(f"{where}: home: expected {self.n} joint angles, got {home!r}")
        if not (np.isfinite(self.stand_s) and self.stand_s > 0.0):
            raise ClipError(f"{where}: stand_s: expected s > 0, got {self.stand_s!r}")
        absent = [w for w in waist if w not in joint_names]
        if absent:
            raise ClipError(f"{where}: waist: joints {absent} are no robot joints")
        self.home = np.asarray(home, dtype=float).copy()
        self._waist_robot = [joint_names.index(w) for w in waist]
        self.total = self.length + self.stand_s

    def frame(self, t: float) -> tuple[int, int, float]:
        """``(i0, i1, blend)`` of time ``t`` s (rl_sar's ``Update``)."""
        frames = self.clip.frames
        f = min(max(t / self.length, 0.0), 1.0) * (frames - 1)
        i0 = int(math.floor(f))
        return i0, min(i0 + 1, frames - 1), f - i0

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The clip at ``t`` s: joint angles (n,) rad and velocities (n,) rad/s in the robot's
        order, and the anchor quaternion (4,) ``w x y z`` in the clip's frame (not aligned);
        past the clip's end, ``stand``'s transition to home (module docstring)."""
        if self.home is not None and t > self.length:
            return self._transition(min((t - self.length) / self.stand_s, 1.0))
        i0, i1, b = self.frame(t)
        pos = self.pos[i0] * (1.0 - b) + self.pos[i1] * b
        vel = self.vel[i0] * (1.0 - b) + self.vel[i1] * b
        root = slerp(self.clip.root_quat[i0], self.clip.root_quat[i1], b)
        jp = self.clip.joint_pos
        waist = jp[i0, self.waist] * (1.0 - b) + jp[i1, self.waist] * b
        return pos, vel, torso_quat(root, waist)

    def _transition(self, a: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``stand``'s reference at blend ``a`` in [0, 1] from the last frame to home."""
        last = self.clip.frames - 1
        pos = self.pos[last] + a * (self.home - self.pos[last])
        vel = (1.0 - a) * self.vel[last]
        root = self.clip.root_quat[last]
        root = slerp(root, yaw_only(root[None])[0], a)
        return pos, vel, torso_quat(root, pos[self._waist_robot])

    def reference_poses(self) -> np.ndarray:
        """(F, n) rad: the joint angles the reference passes through, a row per frame of the
        clip then per 1 / fps s of ``stand``'s transition (:meth:`reference_index`)."""
        rows = [self.pos]
        if self.home is not None:
            steps = int(np.ceil(self.stand_s * self.clip.fps))
            rows.append(np.array([self._transition(k / steps)[0] for k in range(1, steps + 1)]))
        return np.concatenate(rows)

    def reference_index(self, t: float) -> int:
        """The row of :meth:`reference_poses` nearest the reference at ``t`` s."""
        if t <= self.length:
            i0, _, b = self.frame(t)
            return i0 + int(round(b))
        last = self.clip.frames - 1
        if self.home is None:
            return last
        steps = int(np.ceil(self.stand_s * self.clip.fps))
        return last + int(round(min((t - self.length) / self.stand_s, 1.0) * steps))

    def align(self, envs: np.ndarray, base_quat: np.ndarray, waist_angles: np.ndarray) -> None:
        """The yaw alignment of the envs of the bool mask ``envs`` (rl_sar's ``Reset``) from each
        robot's base quaternion (envs, 4) ``w x y z`` and waist angles (envs, 3) rad (yaw, roll,
        pitch) now: ``yaw(robot torso) * conj(yaw(clip torso at t = 0))``."""
        envs = np.asarray(envs, dtype=bool)
        robot = torso_quat(base_quat[envs], waist_angles[envs])
        clip = self.sample(0.0)[2]
        self.init[envs] = quat_mul(yaw_only(robot), quat_conj(yaw_only(clip)))

    def start(self, envs: np.ndarray) -> None:
        """Start the clip (time 0) for the envs of ``envs``, keeping their alignment."""
        envs = np.asarray(envs, dtype=bool)
        self.time[envs] = 0.0
        self.plays[envs] += 1

    def stop(self, envs: np.ndarray) -> None:
        """The envs of ``envs`` are not playing (time NaN): they read the first frame."""
        self.time[np.asarray(envs, dtype=bool)] = np.nan

    def finished(self) -> np.ndarray:
        """(envs,) bool: the clip has reached its end (``time >= length``)."""
        with np.errstate(invalid="ignore"):
            return self.time >= self.length

    def write(self, out: np.ndarray, envs: np.ndarray | None = None) -> None:
        """Write each started env's reference into ``out`` (envs, 2n + 4): joint angles, joint
        velocities, the aligned anchor ``init * anchor`` (``RobotState.motion``); an env not
        started reads the clip's first frame, unaligned."""
        rows = range(self.envs) if envs is None else np.flatnonzero(envs)
        n = self.n
        for e in rows:
            t = self.time[e]
            pos, vel, anchor = self.sample(0.0 if np.isnan(t) else min(t, self.total))
            out[e, :n], out[e, n : 2 * n] = pos, vel
            out[e, 2 * n : 2 * n + 4] = quat_mul(self.init[e], anchor)

    def advance(self, dt: float, envs: np.ndarray) -> None:
        """``dt`` s on for the started envs of ``envs`` (a ``loop`` clip past its end starts over
        at 0, keeping its alignment; ``once`` and ``hold`` stay at the end, ``stand`` at its
        transition's end)."""
        envs = np.asarray(envs, dtype=bool) & ~np.isnan(self.time)
        self.time[envs] += dt
        self.restarted.fill(False)
        if self.playback in ("loop", "exhibition"):
            end = self.length if self.playback == "loop" else self.total + self.rest_s
            over = envs & (self.time >= end - 1e-9)
            self.time[over] = 0.0
            self.plays[over] += 1
            self.restarted |= over
        else:
            np.minimum(self.time, self.total, out=self.time, where=envs)

    def state_dict(self, env: int | None = None) -> dict:
        """``time`` (envs,) s, ``init`` (envs, 4), ``plays`` (envs,) (one env's: ``env``)."""
        pick = slice(None) if env is None else slice(env, env + 1)
        return {k: getattr(self, k)[pick].copy() for k in ("time", "init", "plays")}

    def load_state_dict(self, state: dict, env: int | None = None) -> None:
        """Inverse of :meth:`state_dict`."""
        pick = slice(None) if env is None else slice(env, env + 1)
        for k in ("time", "init", "plays"):
            getattr(self, k)[pick] = state[k]
