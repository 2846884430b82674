"""The ground floor: the contracts every room above shares and nothing below it defines.

The runtime's state (:mod:`sim2real.deploy.core.state`: ``RobotState``, ``BaseState``, ``Kinematics``),
what a backend reads and what a plant is (:mod:`sim2real.deploy.core.backend`), the state machine's modes
and fault causes (:mod:`sim2real.deploy.core.modes`), the per-stage latency histograms
(:mod:`sim2real.deploy.core.latency`), quaternion math (:mod:`sim2real.deploy.core.attitude`) and the helpers
of a stage's per-env state (:mod:`sim2real.deploy.core.stateful`). A module here imports only ``robots`` and
the compiled helpers of :mod:`sim2real.deploy.kernels`.
"""
