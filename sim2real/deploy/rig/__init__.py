"""The one assembly of a run: :class:`sim2real.deploy.rig.rig.Rig` (the runtime, the monitors and the task
every run has) and its after-tick hooks (:class:`sim2real.deploy.rig.hooks.RunHook`; those ``deploy-run``
switches on from the command line register in :mod:`sim2real.deploy.rig.hooks`). ``deploy-run``, the
soak's batch, the training environments and the runtime's acceptance run build their runs here (a
test keeps every other ``Runtime(...)`` out of the package).

The package imports nothing itself: the command line registers hooks without importing numba or
MuJoCo.
"""
