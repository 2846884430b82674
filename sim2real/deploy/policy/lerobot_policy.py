"""An exported LeRobot policy run beside a faster servo loop (:class:`LeRobotChunkPolicy`): the
ONNX graph of :mod:`sim2real.deploy.export.lerobot_act` called once per chunk (the action queue)
or once per policy tick (temporal ensembling), one action per policy tick at the contract's
``fps``, held between policy ticks as the servo loop's joint target; and the robot's joints in
LeRobot's units (:data:`LEROBOT_UNITS`).

Units: lerobot 0.4.4's SO-100/SO-101 follower (``lerobot/robots/so_follower/so_follower.py``
lines 51-60, ``config_so_follower.py`` line 43 ``use_degrees: bool = True``) reads and writes the
five arm joints in degrees (``MotorNormMode.DEGREES``: 0 at the middle of the calibrated range) and
the gripper in percent of its calibrated range (``MotorNormMode.RANGE_0_100``). Here degrees are
about the MJCF's zero, and the gripper's calibrated range is the MJCF's hard limits of the gripper
joint: a real arm's calibration must put those where they are in the MJCF.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from sim2real.deploy.policy.action_chunks import ActionChunks
from sim2real.deploy.spec.foreign import lerobot as lr

#: Per robot, LeRobot's unit of each joint in our joint order: ``deg`` (degrees) or ``range_0_100``
#: (percent of the joint's range, our hard limits). Module docstring for the sources.
LEROBOT_UNITS: dict[str, tuple[str, ...]] = {
    "so101": ("deg", "deg", "deg", "deg", "deg", "range_0_100"),
}


class LeRobotChunkPolicy:
    """A LeRobot export driving one robot's joint targets (module docstring).

    Args:
        path: The ONNX file ``policy-export FOLDER`` wrote (its ``lerobot_contract`` metadata).
        robot: Our robot description; its name must be in :data:`LEROBOT_UNITS` and its joints
            as many as the contract's state and action entries.

    Attributes:
        contract: The file's :class:`~sim2real.deploy.spec.foreign.lerobot.LeRobotContract`.
        chunks: The :class:`~sim2real.deploy.policy.action_chunks.ActionChunks` executor.
        period: s, one policy tick (``1 / fps``).
        target: (n,) rad, the joint target of the last policy tick (None before the first).
        policy_ticks: Policy ticks so far. boundaries: Policy tick indices at which a new chunk
            was taken (the queue scheme; every tick with ensembling).

    Raises:
        lr.LeRobotFormatError: the file has no contract, no fps, or the robot does not fit.
    """

    def __init__(self, path: str | Path, robot):
        import onnxruntime as ort

        self.contract = c = lr.read_onnx(path)
        units = LEROBOT_UNITS.get(robot.name)
        if units is None:
            raise lr.LeRobotFormatError(
                f"{path}: robot {robot.name!r} has no LeRobot joint units (known: "
                f"{', '.join(LEROBOT_UNITS)})"
            )
        if c.state_dim != robot.n_joints or c.action_dim != robot.n_joints:
            raise lr.LeRobotFormatError(
                f"{path}: state {c.state_dim} and action {c.action_dim} entries, robot "
                f"{robot.name} has {robot.n_joints} joints"
            )
        if c.fps is None:
            raise lr.LeRobotFormatError(f"{path}: the contract has no fps")
        self.units = np.array([u == "deg" for u in units])
        self.lower = np.asarray(robot.position_lower, float)
        self.upper = np.asarray(robot.position_upper, float)
        self.session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        self.chunks = ActionChunks(c.chunk_size, c.n_action_steps, c.temporal_ensemble_coeff)
        self.period = 1.0 / c.fps
        self.policy_ticks = 0
        self.boundaries: list[int] = []
        self.reset()

    def reset(self) -> None:
        """An episode's start: no queued action, the next :meth:`step` is a policy tick (and a
        network call). The counters (``policy_ticks``, ``boundaries``) run on."""
        self.chunks.reset()
        self.target: np.ndarray | None = None
        self._next = None

    def to_lerobot(self, q: np.ndarray) -> np.ndarray:
        """(n,) rad -> LeRobot's state (degrees, gripper percent), float32."""
        pct = (q - self.lower) / (self.upper - self.lower) * 100.0
        return np.where(self.units, np.rad2deg(q), pct).astype(np.float32)

    def to_joints(self, action: np.ndarray) -> np.ndarray:
        """LeRobot's action (degrees, gripper percent) -> (n,) rad."""
        a = np.asarray(action, float)
        rad = self.lower + a / 100.0 * (self.upper - self.lower)
        return np.where(self.units, np.deg2rad(a), rad)

    def step(
        self,
        t: float,
        q: np.ndarray,
        frames: Mapping[str, np.ndarray],
        env_state: np.ndarray | None = None,
    ) -> np.ndarray:
        """The joint target (n,) rad at time ``t`` s of the servo loop: a new action when a policy
        period has passed since the last (the graph called when a chunk is needed, with the
        state ``q`` rad, ``frames``: per camera key a float32 ``(3, H, W)`` image in ``[0, 1]``,
        RGB, and ``env_state``, the policy's ``observation.environment_state`` if it has one),
        else the last one held."""
        if self._next is not None and t < self._next - 1e-9:
            return self.target
        self._next = t + self.period if self._next is None else self._next + self.period
        calls = self.chunks.calls

        def predict():
            feed = {lr.STATE_KEY: self.to_lerobot(q)[None]}
            if self.contract.env_state_dim:
                es = np.asarray(env_state, dtype=np.float32).reshape(1, -1)
                if es.shape[1] != self.contract.env_state_dim:
                    raise ValueError(
                        f"{lr.ENV_STATE_KEY}: {es.shape[1]} entries, expected "
                        f"{self.contract.env_state_dim}"
                    )
                feed[lr.ENV_STATE_KEY] = es
            for key, shape in self.contract.cameras:
                img = np.asarray(frames[key], dtype=np.float32)
                if img.shape != shape:
                    raise ValueError(f"camera {key}: frame of shape {img.shape}, expected {shape}")
                feed[key] = img[None]
            return self.session.run(None, feed)[0]

        self.target = self.to_joints(self.chunks.step(predict))
        if self.chunks.calls != calls:
            self.boundaries.append(self.policy_ticks)
        self.policy_ticks += 1
        return self.target
