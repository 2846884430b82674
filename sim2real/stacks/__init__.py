"""The other stacks, one module each, every face of :class:`sim2real.deploy.core.stacks.Stack`
named there (:data:`~sim2real.deploy.core.stacks.FACES`): ``rl_sar``, ``holosoma``, ``mjlab``,
``isaaclab`` (Isaac Lab, unitree_rl_lab), ``unitree_deploy`` (Unitree's deploy.yaml),
``legged_gym`` (unitree_rl_gym, HIMLoco, humanoid-gym), ``beyondmimic``, ``robomimic``
(RoboMimic_Deploy), ``lerobot`` (its ACT folders). Importing this package imports every module
of it (a new stack is one new module here, or one outside the tree with an entry point of the
group ``sim2real.stacks``); the registry imports it when it is first listed.
:mod:`sim2real.stacks.loops` holds the stacks' own loops, written from their sources, that the
push benchmark and the tracking comparisons run.

The floors: these modules name the faces as ``"module:attribute"``, imported by the room that asks
for one, so a stack module imports nothing but the registry (its floor is the top one).
"""

import importlib
import pkgutil

for _module in pkgutil.iter_modules(__path__):
    if not _module.ispkg and not _module.name.startswith("_"):
        importlib.import_module(f"{__name__}.{_module.name}")
