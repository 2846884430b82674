"""The SO-101's front and wrist cameras on a simulated plant (:class:`SceneCameras`), as LeRobot's
SO-101 setups name them (``observation.images.front``, ``observation.images.wrist``): each the
plant's colour camera (:class:`~sim2real.deploy.backends.sim.rgb_camera.PlantRgbCamera`, the
OV5647's noise and the exposure drift) rendering the robot's task scene
(``sim2real/robots/so101/so101_scene.xml``: the cameras, the goal marker, a table) at a rate of
their own, the goal marker at the run's goal.

:meth:`SceneCameras.capture` gives the frames a LeRobot dataset records (uint8 (rows, columns, 3)
R, G, B). A policy run renders the same scene's cameras through the runtime's camera stage
(:func:`sim2real.deploy.backends.sim.camera.attach_plant_camera`: one plant camera per camera key of
the policy, each through its own camera stage).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from sim2real.deploy.backends.sim.rgb_camera import PlantRgbCamera
from sim2real.deploy.backends.sim.task_scene import task_scene
from sim2real.deploy.spec.camera import RgbImageBlock

#: LeRobot's SO-101 camera names (its SO-101 examples: a "front" and a "wrist" camera).
CAMERAS = ("front", "wrist")
#: (rows, columns) rendered by default: 4:3 as LeRobot's 640 x 480 cameras, small enough for a
#: CPU to train ACT's ResNet-18 on (our choice).
SHAPE = (96, 128)
#: A LeRobot image feature's key.
KEY = "observation.images.{}"


class SceneCameras:
    """The cameras ``names`` of env 0 of ``plant`` (a :class:`~sim2real.deploy.backends.sim.
    plant.SimBackend` of ``robot``), rendering the robot's task scene.

    Args:
        robot: The robot (its robot.toml ``[task] scene`` names the scene).
        plant: The simulated plant. rate: Frames per second (the dataset's or the policy's fps).
        shape: (rows, columns). names: The scene's ``<camera>`` names. seed: Of the sensor noise.

    Raises:
        ValueError: the robot has no task scene. CameraError: the scene lacks a camera (one line
            naming the scene file).
    """

    def __init__(
        self,
        robot,
        plant,
        rate: float,
        shape: tuple[int, int] = SHAPE,
        names=CAMERAS,
        seed: int = 0,
    ):
        self.scene = task_scene(robot, plant)
        if self.scene is None:
            raise ValueError(f"{robot.directory / 'robot.toml'}: [task] scene is not set")
        self.names, self.shape, self.rate = tuple(names), tuple(shape), float(rate)
        self.cameras = {}
        for i, name in enumerate(self.names):
            block = RgbImageBlock(
                input=KEY.format(name), camera=name, shape=self.shape, resize=self.shape, rate=rate
            )
            self.cameras[name] = PlantRgbCamera(
                plant, block, seed=seed + i, where=f"{self.scene.path}: camera", scene=self.scene
            )
        self._frames = {n: SimpleNamespace(time=0.0, rgb_image=None) for n in self.names}
        self.goal = np.zeros((plant.envs, 3))
        self.scene.goal = self.goal

    def capture(self, t: float, goal) -> dict[str, np.ndarray]:
        """Per camera name, the newest frame delivered by ``t`` s (uint8 (rows, columns, 3) R, G,
        B; frames are captured at multiples of ``1 / rate`` s, the plant as it is now), the goal
        marker at ``goal`` (3,) m."""
        self.goal[:] = np.asarray(goal, float)
        out = {}
        for name, cam in self.cameras.items():
            frame = self._frames[name]
            frame.time = t
            cam.fill(frame)
            out[name] = frame.rgb_image[0].copy()
        return out

    def close(self) -> None:
        for cam in self.cameras.values():
            cam.close()
