"""The ground floor: the contracts every room above shares and nothing below it defines.

The runtime's state (:mod:`deploy.core.state`: ``RobotState``, ``BaseState``, ``Kinematics``),
what a backend reads and what a plant is (:mod:`deploy.core.backend`), the state machine's modes
and fault causes (:mod:`deploy.core.modes`), the per-stage latency histograms
(:mod:`deploy.core.latency`), quaternion math (:mod:`deploy.core.attitude`) and the helpers of a
stage's per-env state (:mod:`deploy.core.stateful`). A module here imports only ``robots`` and
the compiled helpers of :mod:`deploy.kernels`.
"""
