"""The simulator's true state of a plant's envs, for evaluation only (:class:`TrueState`): what
the soak, the monitors and the benchmarks judge a run by, and what no deployment can read.

:class:`TrueState` is a stage of :class:`~sim2real.deploy.backends.sim.plant.SimBackend`, which
delegates ``true_position``, ``true_velocity``, ``true_base_state``, ``end_effector_position``
and ``ground_height`` to it. It reads the plant's ``MjData`` through the plant's per-env views
(lists the plant shares with it, rebound in place for a new model) and gathers the joints into
the plant's arrays (those its compiled step gathers into at the end of each period), and holds
the grounds under the envs (``grounds``: set by whoever laid a terrain into the envs' models).
"""

from __future__ import annotations

from operator import is_

import numba
import numpy as np

from sim2real.deploy.kernels.calls import bind, pointer


class TrueState:
    """The true state of ``robot``'s envs (module docstring).

    Args:
        robot: The robot. datas: The plant's ``MjData``, one per env. views: The plant's
            per-env views ``(model, data, ctrl, qpos, force, warnings)``. qvel_views: The
            joints' ``qvel`` per env. qpos, qvel: (envs, n) the plant's gathered joint state.
            free_base: The plant's models begin with the free joint (its floating base).

    Attributes:
        grounds: Per env, the ground of a plant whose floor is not the plane z = 0: an object
            with ``height_at(x, y) -> m`` (:class:`sim2real.eval.world.terrain.GroundMap`);
            None (default): every env on the plane.
    """

    def __init__(
        self, robot, datas: list, views: list, qvel_views: list, qpos, qvel, free_base: bool
    ):
        self.robot, self.datas, self.views, self.qvel_views = robot, datas, views, qvel_views
        self.free_base = free_base
        self.qpos, self.qvel = qpos, qvel
        self.grounds: list | None = None
        #: ``(datas, call, base)``: :meth:`base_state`'s compiled gather of each ``MjData``'s
        #: free joint (:meth:`_bind_base`), bound again when an env's data is another
        self._base_views: tuple | None = None
        if free_base:  # compiled (or loaded) now, not at the first tick
            gather_base(np.zeros((0, 2), dtype=np.int64), np.zeros((0, 13)))

    def position(self) -> np.ndarray:
        """(envs, n_joints) rad, the simulator's joint angles (evaluation only)."""
        for e, (_m, _d, _ctrl, qpos, _force, _warnings) in enumerate(self.views):
            self.qpos[e] = qpos
        return self.qpos

    def velocity(self) -> np.ndarray:
        """(envs, n_joints) rad/s, the simulator's joint velocities (evaluation only)."""
        for e, qvel in enumerate(self.qvel_views):
            self.qvel[e] = qvel
        return self.qvel

    def base_state(self, out: np.ndarray | None = None) -> np.ndarray:
        """(envs, 13) the floating base's true state (evaluation only): position (m, world),
        orientation (unit quaternion w, x, y, z: base to world), linear velocity (m/s, world)
        and angular velocity (rad/s, base frame), MuJoCo's free-joint ``qpos[:7]`` and
        ``qvel[:6]``.

        Raises:
            ValueError: a fixed-base robot.
        """
        if not self.free_base:
            raise ValueError(f"robot {self.robot.name} has no floating base")
        datas, kept = self.datas, self._base_views
        if kept is None or len(kept[0]) != len(datas) or not all(map(is_, datas, kept[0])):
            kept = self._base_views = self._bind_base(datas)
        kept[1]()  # gather_base: every env's free joint into the kept (envs, 13) array
        if out is None:
            return kept[2].copy()
        out[...] = kept[2]
        return out

    @staticmethod
    def _bind_base(datas: list) -> tuple:
        """``(datas, call, base)``: :func:`gather_base` bound to each ``MjData``'s ``qpos`` and
        ``qvel`` addresses (MuJoCo's arrays live as long as their data, which the tuple keeps)
        and the (envs, 13) array it fills."""
        addresses = np.array([[d.qpos.ctypes.data, d.qvel.ctypes.data] for d in datas])
        base = np.zeros((len(datas), 13))
        return list(datas), bind(gather_base, addresses.astype(np.int64), base), base

    def __getstate__(self) -> dict:
        """A copy (``copy.deepcopy``, pickle) binds :meth:`base_state`'s call afresh: the
        addresses it holds are the original ``MjData``'s."""
        return self.__dict__ | {"_base_views": None}

    def end_effector_position(self, out: np.ndarray | None = None) -> np.ndarray:
        """(envs, 3) m, the end-effector site in the world frame (evaluation only).

        MuJoCo computes it at the start of the last physics step: it is one physics timestep
        behind :meth:`position`. ``out``: optional (envs, 3) float64 array to fill (no
        allocation); returned.
        """
        sid = self.robot.ee_site_id
        if out is None:
            return np.stack([d.site_xpos[sid] for d in self.datas])
        for e, d in enumerate(self.datas):
            out[e] = d.site_xpos[sid]
        return out

    def ground_height(self, truth: np.ndarray) -> np.ndarray:
        """(envs,) m, the ground's height under each env's true base (``truth`` (envs, 13),
        :meth:`base_state`): its ground's (:attr:`grounds`), 0 on the plane."""
        out = np.zeros(len(truth))
        for e, ground in enumerate(self.grounds or ()):
            if ground is not None:
                out[e] = float(ground.height_at(truth[e, 0], truth[e, 1]))
        return out


@numba.njit(cache=True, nogil=True)
def gather_base(addresses: np.ndarray, base: np.ndarray) -> None:
    """Into ``base`` (envs, 13), each env's free joint: ``qpos[:7]`` and ``qvel[:6]`` of the
    ``MjData`` whose ``qpos`` and ``qvel`` addresses are row ``e`` of ``addresses`` (envs, 2)
    int64 (:meth:`TrueState.base_state`)."""
    for e in range(base.shape[0]):
        qpos = numba.carray(pointer(addresses[e, 0]), (7,), np.float64)
        qvel = numba.carray(pointer(addresses[e, 1]), (6,), np.float64)
        for i in range(7):
            base[e, i] = qpos[i]
        for i in range(6):
            base[e, 7 + i] = qvel[i]
