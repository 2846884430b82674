"""A Unitree robot's low-level interface: ``deploy-run --backend unitree`` over Cyclone DDS.

The messages are Unitree's, written from its public IDL as member tables that :mod:`.idl` builds
into structs: :mod:`.unitree_go` (Go2, Go1, B2, H1), :mod:`.unitree_hg` (G1, H1-2),
:mod:`.unitree_api` (service requests). :mod:`.layout` derives
their C and XCDR1 layouts, :mod:`.crc` the CRC-32 the robot checks, :mod:`.codec` encodes and
decodes them through numpy records, :mod:`.family` holds what differs between the families,
:mod:`.dds` the domain, writers and readers of encoded samples, :mod:`.motion_switcher` the
sport-mode check. :mod:`.backend` is the :class:`~sim2real.deploy.core.backend.Backend`,
:mod:`.bringup` its ``open()``, :mod:`.options` its registration; :mod:`.emulator` stands in for
the robot with the MuJoCo plant.

Importing this package needs nothing; its modules need ``cyclonedds`` (extra ``unitree``).
"""
