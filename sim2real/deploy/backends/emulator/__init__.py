"""Hardware-in-the-loop without hardware: a servo bus on a pseudo-terminal, backed by the plant.

``python -m sim2real.deploy.backends.emulator --robot so101 --protocol feetech`` prints a pty path and
answers on it as the robot's servos would (Feetech SCS/STS protocol or Dynamixel Protocol 2.0,
the real control tables); the MuJoCo plant (:class:`sim2real.deploy.backends.sim.plant.SimBackend`) runs
behind the registers. In-process::

    with ServoBusEmulator(load_robot("so101"), "feetech") as emu:
        port = emu.port  # open it with the vendor's SDK

Modules: :mod:`.bus` (pty loop, plant, timing model, faults), :mod:`.dispatch` (instructions per
protocol), :mod:`.servo` (one servo's registers and protection), :mod:`.faults` (wire faults).
The packet codecs and control tables live in :mod:`sim2real.deploy.backends.servo`.
"""

from sim2real.deploy.backends.emulator.bus import PROTOCOLS, ServoBusEmulator
from sim2real.deploy.backends.emulator.faults import WireFaults, parse_fault

__all__ = ["PROTOCOLS", "ServoBusEmulator", "WireFaults", "parse_fault"]
