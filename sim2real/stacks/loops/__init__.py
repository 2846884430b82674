"""The stacks' own loops (each stack's ``own_loop`` face, :mod:`sim2real.stacks`): bare MuJoCo
loops written from another stack's source (read, not copied) that run a policy as that stack's
own runtime does, the reference ``deploy-run``, the push benchmark and the fall replays are
compared with: rl_sar's legged loop (:mod:`.himloco_terrain_loop`, its robot
:mod:`.rl_sar_robot`) and tracking loop (:mod:`.rl_sar_tracking`, :mod:`.rl_sar_motion`), Unitree's
deploy.yaml runtime (:mod:`.deploy_yaml_loop`), unitree_rl_gym's ``deploy_mujoco.py``
(:mod:`.unitree_rl_gym`), RoboMimic_Deploy's dance (:mod:`.robomimic_dance`).
"""
