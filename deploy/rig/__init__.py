"""The one assembly of a run: :class:`deploy.rig.rig.Rig` (the runtime, the monitors and the task
every run has) and its after-tick hooks (:class:`deploy.rig.hooks.RunHook`; those ``deploy-run``
switches on from the command line register in :mod:`deploy.rig.hooks`). ``deploy-run``, the
soak's batch and the training environments build their runs here.

The package imports nothing itself: the command line registers hooks without importing numba or
MuJoCo.
"""
