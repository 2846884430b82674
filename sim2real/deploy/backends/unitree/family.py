"""The two low-level message families and what differs between them.

``unitree_go`` (Go2, Go1, B2, H1): 20 motor slots; a command starts ``head`` 0xFE 0xEF and
``level_flag`` 0xFF (low level; unitree_sdk2's Go2 examples); the state carries ``foot_force``, a
motor's ``lost`` packet count and one temperature. ``unitree_hg`` (G1, H1-2): 35 motor slots; a
command echoes the robot's ``mode_machine`` (its LowState_'s) and sets ``mode_pr`` (0: series
pitch/roll control of the ankles and waist); a motor reports two temperatures and a
``motorstate`` word.

Functions of a :class:`Family` read and write the records of
:class:`sim2real.deploy.backends.unitree.codec.MessageCodec` (numpy, C layout), indexed by motor slot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim2real.deploy.backends.unitree import unitree_go, unitree_hg

#: Topics of the low-level interface (unitree_sdk2; the same on every robot).
TOPIC_LOWCMD = "rt/lowcmd"
TOPIC_LOWSTATE = "rt/lowstate"
#: ``unitree_go`` command header and level flag (unitree_sdk2 Go2 examples: 0xFE 0xEF, 0xFF).
GO_HEAD = (0xFE, 0xEF)
GO_LOW_LEVEL = 0xFF


@dataclass(frozen=True)
class Family:
    """One message family (module docstring).

    Attributes:
        name: ``unitree_go`` or ``unitree_hg``. low_cmd, low_state: the IdlStruct types.
        motors: Motor slots in a message. has_feet: the state carries ``foot_force``.
        has_mode_machine: the state reports, and a command must echo, ``mode_machine``.
    """

    name: str
    low_cmd: type
    low_state: type
    motors: int
    has_feet: bool
    has_mode_machine: bool

    def init_command(self, cmd: np.ndarray, mode_machine: int = 0) -> None:
        """The fixed fields of a command record ``cmd``: the ``unitree_go`` header and level, or
        the ``unitree_hg`` ``mode_machine`` (echoed from the robot) and ``mode_pr`` 0."""
        if self.name == "unitree_go":
            cmd["head"] = GO_HEAD
            cmd["level_flag"] = GO_LOW_LEVEL
        else:
            cmd["mode_pr"] = 0
            cmd["mode_machine"] = mode_machine

    def temperature(self, state: np.ndarray, slots: np.ndarray) -> np.ndarray:
        """(len(slots),) degC each motor reports (``unitree_hg``: the hotter of its two)."""
        t = state["motor_state"]["temperature"][slots]
        return t.astype(np.float64) if t.ndim == 1 else t.max(axis=1).astype(np.float64)

    def lost(self, state: np.ndarray, slots: np.ndarray) -> np.ndarray | None:
        """(len(slots),) uint32 packets each motor lost (a running count), or None
        (``unitree_hg`` reports none)."""
        if self.name != "unitree_go":
            return None
        return state["motor_state"]["lost"][slots]

    def errors(self, state: np.ndarray, slots: np.ndarray) -> np.ndarray:
        """(len(slots),) int64 driver error code of each motor (0: none): ``unitree_go``
        ``reserve[0]`` (the motor's error code, as Unitree's motors report it: 4 over
        temperature, unitree_actuator_sdk), ``unitree_hg`` ``motorstate``."""
        ms = state["motor_state"]
        if self.name == "unitree_go":
            return ms["reserve"][slots, 0].astype(np.int64)
        return ms["motorstate"][slots].astype(np.int64)

    def mode_machine(self, state: np.ndarray) -> int | None:
        """The robot's ``mode_machine`` (``unitree_hg``), else None."""
        return int(state["mode_machine"]) if self.has_mode_machine else None


FAMILIES = {
    "unitree_go": Family(
        "unitree_go", unitree_go.LowCmd_, unitree_go.LowState_, unitree_go.MOTORS, True, False
    ),
    "unitree_hg": Family(
        "unitree_hg", unitree_hg.LowCmd_, unitree_hg.LowState_, unitree_hg.MOTORS, False, True
    ),
}


def family(name: str) -> Family:
    """The family called ``name``.

    Raises:
        ValueError: an unknown name (the known ones listed).
    """
    if name not in FAMILIES:
        raise ValueError(f"message family '{name}': expected one of {tuple(FAMILIES)}")
    return FAMILIES[name]
