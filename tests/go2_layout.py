"""unitree_mujoco's ``unitree_robots/go2/go2.xml`` as its layout stands, without its meshes: the
same default classes (``go2``, ``abduction``, ``front_hip``/``back_hip``, ``knee``,
``collision``/``foot``: the foot class places its 0.022 m sphere at ``-0.002 0 -0.213`` on the
calf), a ``base_link`` with a free joint and the ``imu`` site, the legs FL, FR, RL, RR of
``<LEG>_hip``/``_thigh``/``_calf`` bodies on ``<LEG>_<part>_joint`` hinges, each calf with its two
shin cylinders and the foot sphere, an empty ``<LEG>_foot`` body at the calf's end (no geometry:
the simulator's foot is the sphere on the calf), and one ``<motor>`` per joint in its actuator
order (FR, FL, RR, RL). Body placements, masses, collision geoms, friction, joint ranges and
effort ranges are go2.xml's; every leg has the FL leg's inertial and calf cylinders (mirrored in
y), and the visual meshes are left out."""

from __future__ import annotations

from pathlib import Path

#: Legs in go2.xml's body order and each one's hip position's signs (x, y).
LEGS = {"FL": (1, 1), "FR": (1, -1), "RL": (-1, 1), "RR": (-1, -1)}
#: go2.xml's actuator order.
ACTUATORS = [
    f"{leg}_{part}" for leg in ("FR", "FL", "RR", "RL") for part in ("hip", "thigh", "calf")
]
#: m, the foot sphere's radius and its centre on the calf (go2.xml's ``foot`` class).
FOOT_RADIUS, FOOT_POS = 0.022, (-0.002, 0.0, -0.213)

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
        <default class="foot">
          <geom size="0.022" pos="-0.002 0 -0.213" priority="1" condim="6"
            friction="0.4 0.02 0.01" />
        </default>
      </default>
    </default>
  </default>
  <worldbody>
    <body name="base_link" pos="0 0 0.445" childclass="go2">
      <inertial pos="0.021112 0 -0.005366" quat="-0.000543471 0.713435 -0.00173769 0.700719"
        mass="6.921" diaginertia="0.107027 0.0980771 0.0244531" />
      <freejoint />
      <geom size="0.1881 0.04675 0.057" type="box" class="collision" />
      <geom size="0.05 0.045" pos="0.285 0 0.01" type="cylinder" class="collision" />
      <geom size="0.047" pos="0.293 0 -0.06" class="collision" />
      <site name="imu" pos="-0.02557 0 0.04232" />
"""

LEG = """      <body name="{leg}_hip" pos="{x} {y} 0">
        <inertial pos="-0.0054 {iy} -0.000105" quat="0.497014 0.499245 0.505462 0.498237"
          mass="0.678" diaginertia="0.00088403 0.000596003 0.000479967" />
        <joint name="{leg}_hip_joint" class="abduction" />
        <geom size="0.046 0.02" pos="0 {hy} 0" quat="1 1 0 0" type="cylinder" class="collision" />
        <body name="{leg}_thigh" pos="0 {ty} 0">
          <inertial pos="-0.00374 {tiy} -0.0327" quat="0.829533 0.0847635 -0.0200632 0.551623"
            mass="1.152" diaginertia="0.00594973 0.00584149 0.000878787" />
          <joint name="{leg}_thigh_joint" class="{hip}" />
          <geom size="0.1065 0.01225 0.017" pos="0 0 -0.1065" quat="0.707107 0 0.707107 0"
            type="box" class="collision" />
          <body name="{leg}_calf" pos="0 0 -0.213">
            <inertial pos="0.00629595 -0.000622121 -0.141417"
              quat="0.710672 0.00154099 -0.00450087 0.703508"
              mass="0.241352" diaginertia="0.0014901 0.00146356 5.31397e-05" />
            <joint name="{leg}_calf_joint" class="knee" />
            <geom size="0.012 0.06" pos="0.008 0 -0.06" quat="0.994493 0 -0.104807 0"
              type="cylinder" class="collision" />
            <geom size="0.011 0.0325" pos="0.02 0 -0.148" quat="0.999688 0 0.0249974 0"
              type="cylinder" class="collision" />
            <geom name="{leg}" class="foot" />
            <body name="{leg}_foot" pos="0 0 -0.213" />
          </body>
        </body>
      </body>
"""


def write_go2(folder: Path) -> Path:
    """go2.xml's layout (module docstring) written into ``folder``; returns its path."""
    legs = "".join(
        LEG.format(
            leg=leg,
            x=0.1934 * sx,
            y=0.0465 * sy,
            iy=0.00194 * sy,
            hy=0.08 * sy,
            ty=0.0955 * sy,
            tiy=-0.0223 * sy,
            hip="front_hip" if sx > 0 else "back_hip",
        )
        for leg, (sx, sy) in LEGS.items()
    )
    classes = {"hip": "abduction", "thigh": "hip", "calf": "knee"}
    motors = "".join(
        f'    <motor class="{classes[a[3:]]}" name="{a}" joint="{a}_joint" />\n' for a in ACTUATORS
    )
    path = Path(folder) / "go2.xml"
    path.write_text(
        f"{HEAD}{legs}    </body>\n  </worldbody>\n  <actuator>\n{motors}  </actuator>\n</mujoco>\n"
    )
    return path
