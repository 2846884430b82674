"""Hardware in the loop without the robot: a Unitree robot's low-level DDS topics, backed by the
MuJoCo plant.

``python -m sim2real.deploy.backends.unitree.emulator --robot go2`` publishes ``rt/lowstate`` at 500 Hz,
takes ``rt/lowcmd`` (CRC checked) and answers the motion switcher on the loopback interface,
DDS domain 1 (Unitree's simulation bridges' default); ``deploy-run --backend unitree
--network-interface lo --domain-id 1`` drives it as it would the robot. In-process::

    with UnitreeEmulator(load_robot("go2"), domain_id=7) as emu:
        ...  # UnitreeBackend(robot, interface="lo", domain_id=7)

Modules: :mod:`.robot` (the plant thread, commands in, states out), :mod:`.drivers` (the motor
drivers' PD and cut-off), :mod:`.lowstate` (the state a board reports), :mod:`.services` (the
motion switcher), :mod:`.faults` (what goes wrong), :mod:`.hil` (deploy-run against it).
"""

from sim2real.deploy.backends.unitree.emulator.faults import EmulatorFaults, parse_fault
from sim2real.deploy.backends.unitree.emulator.robot import UnitreeEmulator

__all__ = ["EmulatorFaults", "UnitreeEmulator", "parse_fault"]
