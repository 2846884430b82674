"""``deploy-run --backend unitree``: a Unitree robot's low-level DDS interface, its registration
and options (:mod:`sim2real.deploy.backends.registry`)."""

from __future__ import annotations

from sim2real.deploy.backends.real_robot import refuse_simulation_options
from sim2real.deploy.backends.registry import register_backend


def add_options(group) -> None:
    """The DDS options: network interface, domain, message family, bring-up."""
    group.add_argument(
        "--network-interface",
        default=None,
        metavar="IF",
        help="network interface the robot is on (e.g. eth0; lo for the emulator); default: "
        "Cyclone DDS chooses",
    )
    group.add_argument(
        "--domain-id",
        type=int,
        default=0,
        help="DDS domain (Unitree robots 0, Unitree's simulation bridges 1)",
    )
    group.add_argument(
        "--family",
        choices=("unitree_go", "unitree_hg"),
        default=None,
        help="message family (default: robot.toml [unitree] family; unitree_go: Go2, H1; "
        "unitree_hg: G1, H1-2)",
    )
    group.add_argument(
        "--lowstate-timeout",
        type=float,
        default=5.0,
        help="s to wait for the first LowState",
    )
    group.add_argument(
        "--lowcmd-rate",
        type=float,
        default=None,
        metavar="HZ",
        help="re-send the last LowCmd at this rate between the policy's ticks (default 500, as "
        "Unitree's examples; 0: one a control period)",
    )
    group.add_argument(
        "--lowstate-unchecked",
        action="store_true",
        help="accept LowState samples with no CRC and no tick (crc 0), as Unitree's simulation "
        "bridges (unitree_mujoco) publish them; never for a robot",
    )
    group.add_argument(
        "--skip-sport-mode-check",
        action="store_true",
        help="do not ask the motion switcher whether a high-level mode is active",
    )


def make(args, robot, mode: str):
    """A Unitree robot over DDS on ``args.network_interface``, domain ``args.domain_id``.

    Raises:
        ValueError: a simulation option given (:func:`refuse_simulation_options`).
        sim2real.deploy.backends.unitree.dds.DdsError: no network interface of that name.
    """
    refuse_simulation_options(
        args, "unitree", "python -m sim2real.deploy.backends.unitree.emulator --fault ..."
    )
    from sim2real.deploy.backends.unitree.backend import UnitreeBackend
    from sim2real.deploy.backends.unitree.dds import check_interface

    check_interface(args.network_interface)  # before Cyclone DDS prints a line of its own

    return UnitreeBackend(
        robot,
        interface=args.network_interface,
        domain_id=args.domain_id,
        family=args.family,
        mode=mode,
        lowstate_timeout=args.lowstate_timeout,
        check_sport_mode=not args.skip_sport_mode_check,
        lowstate_unchecked=args.lowstate_unchecked,
        lowcmd_rate=args.lowcmd_rate,
    )


register_backend(
    "unitree",
    "a Unitree robot's low-level DDS interface (rt/lowcmd, rt/lowstate; wall clock only)",
    "sim2real.deploy.backends.unitree.options:make",
    add_options,
)
