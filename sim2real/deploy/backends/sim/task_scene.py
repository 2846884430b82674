"""What a camera watching a robot's task renders (:class:`TaskScene`): the robot's task scene, an
MJCF that includes the robot's own (robot.toml ``[task] scene``), with a marker at the task's goal
and the cameras that watch the task from outside the robot.

The physics runs the robot's MJCF alone (its description hash, and every policy trained on it,
stay as they are); the scene is drawn, never simulated. Its model holds the robot's bodies and
geoms first, in the robot's order (an ``<include>`` of the robot's MJCF before anything else),
then its own: the mocap body ``goal`` and the cameras. Before each frame, :meth:`TaskScene.sync`
copies an env's joint positions, the geometry of its (possibly randomized) plant model (body and
geom poses and sizes: link lengths drawn per session) and the task's goal into the scene:
the goal marker's position is the goal's, read in the world frame, which is the base frame of a
fixed-base arm whose base sits at the world origin (arm3; checked: ``ValueError`` for a floating
base).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

#: The scene's mocap body that shows the goal.
GOAL_BODY = "goal"


class TaskScene:
    """The task scene of ``envs`` envs of one plant (module docstring).

    Args:
        path: The scene MJCF (robot.toml ``[task] scene``, in the robot's folder).
        plant: The plant (its ``models``, one per env: the robot's MJCF, compiled, replaced
            when a session draws other dynamics).
        floating_base: True for a robot whose base moves (refused: no goal frame yet).

    Attributes:
        models: One scene model per env (their robot part the plant model's). datas: Theirs.
        goal: (envs, 3) m, the goal each env's marker shows, or None (the marker stays where
            the scene puts it); set by the run (``deploy-run``: the runtime's goals; training:
            the episodes').

    Raises:
        ValueError: a scene that does not load, lacks the mocap body ``goal``, or whose joints
            are not the robot's (one line naming the file).
    """

    def __init__(self, path: Path, plant, floating_base: bool = False):
        self.path = Path(path)
        if floating_base:
            raise ValueError(f"{self.path}: a task scene's goal marker needs a fixed base")
        try:
            base = mujoco.MjModel.from_xml_path(str(self.path))
        except (ValueError, OSError) as exc:
            raise ValueError(f"{self.path}: the task scene does not load ({exc})") from None
        body = mujoco.mj_name2id(base, mujoco.mjtObj.mjOBJ_BODY, GOAL_BODY)
        if body < 0 or base.body_mocapid[body] < 0:
            raise ValueError(
                f'{self.path}: expected a mocap body <body name="{GOAL_BODY}" mocap="true"> '
                "showing the goal"
            )
        robot = plant.models[0]
        if base.nq != robot.nq or base.nbody < robot.nbody or base.ngeom < robot.ngeom:
            raise ValueError(
                f"{self.path}: expected the robot's MJCF included first ({robot.nq} joint "
                f"positions, {robot.nbody} bodies), got {base.nq} and {base.nbody}"
            )
        self._mocap = int(base.body_mocapid[body])
        self._nbody, self._ngeom = robot.nbody, robot.ngeom
        self.plant = plant
        self.models = [_copy(base) for _ in plant.models]
        self.datas = [mujoco.MjData(m) for m in self.models]
        self.goal: np.ndarray | None = None

    def sync(self, e: int, plant_data: mujoco.MjData, model: mujoco.MjModel) -> mujoco.MjData:
        """Env ``e``'s scene data with the plant's joint positions and the goal, and ``model``
        (the renderer's copy of the scene's) with the plant model's geometry (module
        docstring); the data returned for the renderer."""
        m, p, d = model, self.plant.models[e], self.datas[e]
        nb, ng = self._nbody, self._ngeom
        m.body_pos[:nb], m.body_quat[:nb] = p.body_pos, p.body_quat
        m.geom_pos[:ng], m.geom_quat[:ng], m.geom_size[:ng] = p.geom_pos, p.geom_quat, p.geom_size
        d.qpos[:] = plant_data.qpos
        if self.goal is not None:
            d.mocap_pos[self._mocap] = self.goal[e]
        return d


def _copy(model: mujoco.MjModel) -> mujoco.MjModel:
    """An independent copy of ``model`` (its arrays written per env)."""
    import copy

    return copy.deepcopy(model)


def task_scene(robot, plant) -> TaskScene | None:
    """The robot's task scene over ``plant``'s models (robot.toml ``[task] scene``), or None
    where the robot has none.

    Raises:
        ValueError: a scene that does not fit the robot (:class:`TaskScene`)."""
    task = getattr(getattr(robot, "config", None), "task", None)
    scene = getattr(task, "scene", None)
    if not scene:
        return None
    models = getattr(plant, "models", ())  # the physics asks its own model: a free joint first
    free = (
        bool(models) and models[0].njnt > 0 and models[0].jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    )
    return TaskScene(robot.directory / scene, plant, free)
