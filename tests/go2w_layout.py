"""unitree_mujoco's ``unitree_robots/go2w/go2w.xml`` as its layout stands, without its meshes:
the same default classes (``go2``, ``abduction``, ``front_hip``/``back_hip``, ``knee``,
``collision``/``foot``), a ``base_link`` with a free joint and the ``imu`` site, the legs FL, FR,
RL, RR of ``<LEG>_hip``/``_thigh``/``_calf``/``_wheel_link`` bodies on ``<LEG>_<part>_joint``
hinges, each wheel's hinge without a range (continuous), and one ``<motor>`` per joint in its
actuator order: the legs FR, FL, RR, RL, then the wheels FR, FL, RR, RL (the order
unitree_mujoco's bridge numbers the motors in). Body placements, masses, joint ranges and
effort ranges are go2w.xml's; the collision geometry is primitives (its wheel a 0.086 m
cylinder where go2w.xml has ``wheel.stl``)."""

from __future__ import annotations

from pathlib import Path

#: Legs in go2w.xml's body order and each one's hip position's signs (x, y).
LEGS = {"FL": (1, 1), "FR": (1, -1), "RL": (-1, 1), "RR": (-1, -1)}
#: go2w.xml's actuator order.
ACTUATORS = [
    f"{leg}_{part}" for leg in ("FR", "FL", "RR", "RL") for part in ("hip", "thigh", "calf")
]
ACTUATORS += [f"{leg}_wheel" for leg in ("FR", "FL", "RR", "RL")]

HEAD = """<mujoco model="go2">
  <compiler angle="radian" autolimits="true" />
  <option cone="elliptic" impratio="100" />
  <default>
    <default class="go2">
      <geom friction="0.4" margin="0.001" condim="1" />
      <joint axis="0 1 0" damping="0.1" armature="0.01" frictionloss="0.2" />
      <motor ctrlrange="-23.7 23.7" />
      <default class="abduction"><joint axis="1 0 0" range="-1.0472 1.0472" /></default>
      <default class="hip">
        <default class="front_hip"><joint range="-1.5708 3.4907" /></default>
        <default class="back_hip"><joint range="-0.5236 4.5379" /></default>
      </default>
      <default class="knee">
        <joint range="-2.7227 -0.83776" /><motor ctrlrange="-45.43 45.43" />
      </default>
      <default class="collision">
        <geom group="3" />
        <default class="foot"><geom priority="1" condim="6" friction="0.8 0.02 0.01" /></default>
      </default>
    </default>
  </default>
  <worldbody>
    <body name="base_link" pos="0 0 0.6" childclass="go2">
      <inertial pos="0.021112 0 -0.005366" mass="6.921" diaginertia="0.107027 0.0980771 0.0244531" />
      <freejoint />
      <geom size="0.1881 0.04675 0.057" type="box" class="collision" />
      <site name="imu" pos="-0.02557 0 0.04232" />
"""

LEG = """      <body name="{leg}_hip" pos="{x} {y} 0">
        <inertial pos="-0.0054 0 0" mass="0.678" diaginertia="0.00088 0.0006 0.00048" />
        <joint name="{leg}_hip_joint" class="abduction" />
        <geom size="0.046 0.02" pos="0 {hy} 0" quat="1 1 0 0" type="cylinder" class="collision" />
        <body name="{leg}_thigh" pos="0 {ty} 0">
          <inertial pos="-0.00374 0 -0.0327" mass="1.152" diaginertia="0.0059 0.0058 0.00088" />
          <joint name="{leg}_thigh_joint" class="{hip}" />
          <geom size="0.1065 0.01225 0.017" pos="0 0 -0.1065" quat="0.707107 0 0.707107 0"
            type="box" class="collision" />
          <body name="{leg}_calf" pos="0 0 -0.213">
            <inertial pos="0.0063 0 -0.1414" mass="0.241352" diaginertia="0.00149 0.00146 5.3e-05" />
            <joint name="{leg}_calf_joint" class="knee" />
            <geom size="0.012 0.06" pos="0.008 0 -0.06" type="cylinder" class="collision" />
            <body name="{leg}_wheel_link" pos="0 0 -0.2264">
              <inertial pos="0 0 0" mass="0.98" diaginertia="0.003 0.0016 0.0016" />
              <joint name="{leg}_wheel_joint" pos="0 0 0" axis="0 1 0" />
              <geom type="cylinder" size="0.086 0.02" quat="1 1 0 0" class="foot" />
            </body>
          </body>
        </body>
      </body>
"""


def write_go2w(folder: Path) -> Path:
    """go2w.xml's layout (module docstring) written into ``folder``; returns its path."""
    legs = "".join(
        LEG.format(
            leg=leg,
            x=0.1934 * sx,
            y=0.0465 * sy,
            hy=0.08 * sy,
            ty=0.0955 * sy,
            hip="front_hip" if sx > 0 else "back_hip",
        )
        for leg, (sx, sy) in LEGS.items()
    )
    motors = "".join(
        f'    <motor name="{a}" joint="{a}_joint"'
        + (' ctrlrange="-15 15"' if a.endswith("wheel") else "")
        + (' class="knee"' if a.endswith("calf") else ' class="go2"')
        + " />\n"
        for a in ACTUATORS
    )
    path = Path(folder) / "go2w.xml"
    path.write_text(
        f"{HEAD}{legs}    </body>\n  </worldbody>\n  <actuator>\n{motors}  </actuator>\n</mujoco>\n"
    )
    return path
