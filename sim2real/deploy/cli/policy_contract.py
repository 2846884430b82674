"""What ``deploy-run`` says and does about a policy's contract before it runs it.

- :func:`contract_messages`: the lines it prints for a policy whose spec came from its training
  stack's own contract (:mod:`sim2real.deploy.spec.foreign`): where it was read, what stood in for what
  was missing, the assumptions; and, for any policy that observes the base's linear velocity, that
  it gets the runtime's estimate.
- :func:`sim2real.deploy.spec.drive.drive_robot` (used by deploy-run): the robot with the policy's PD
  gains and default pose when they differ from robot.toml, and the differences.
- :func:`check_drive_applied`: a backend that neither simulates the plant nor sends its gains with
  each command (``commands_gains``) cannot set its drives' gains: a differing drive is then
  refused, with the values.
"""

from __future__ import annotations


def contract_messages(policy) -> list[str]:
    """``deploy-run: note: ...`` / ``deploy-run: warning: ...`` lines for ``policy`` (an
    :class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy`)."""
    out = []
    contract = getattr(policy, "foreign", None)
    if contract is not None:
        out.append(
            f"deploy-run: note: {contract.format} policy: spec built from its {contract.source}"
        )
        out += [f"deploy-run: note: {contract.format} policy: {line}" for line in contract.missing]
    lerobot = getattr(policy, "contract", None)
    if lerobot is not None and hasattr(policy, "period"):  # a LeRobot export's chunks
        scheme = (
            f"temporal ensembling (coeff {lerobot.temporal_ensemble_coeff:g})"
            if lerobot.temporal_ensemble_coeff is not None
            else f"{lerobot.n_action_steps} of {lerobot.chunk_size} actions per chunk"
        )
        cams = ", ".join(f"'{b.camera}' {b.shape[0]}x{b.shape[1]} RGB" for b in policy.spec.images)
        out.append(
            f"deploy-run: note: LeRobot {lerobot.policy_type} policy at {1 / policy.period:g} Hz "
            f"beside the servo loop, {scheme}; camera {cams or 'none'}; "
            + (
                f"async inference: one policy period ({1e3 * policy.period:g} ms) of latency"
                if getattr(policy, "inference", "sync") == "async"
                else "sync inference: the network call inside the servo tick"
            )
        )
    if any(b.name == "base_linear_velocity" for b in policy.spec.observation_blocks):
        terms = contract.base_velocity_terms() if contract is not None else []
        named = f" (term {', '.join(map(repr, terms))})" if terms else ""
        out.append(
            f"deploy-run: warning: the policy observes the base's linear velocity{named}: it gets "
            "the runtime's base estimator's estimate (IMU and leg-odometry Kalman filter, "
            "sim2real.deploy.estimation.base), not a measurement; its error is the policy's input error"
        )
    return out


def check_drive_applied(differences: dict[str, str], sets_gains: bool, backend_name: str) -> None:
    """Refuse differing PD gains on a backend that cannot set them (``sets_gains`` False: not
    the simulated plant, and no ``commands_gains`` of
    :class:`~sim2real.deploy.core.backend.BackendLifecycle`); a differing default pose is the
    runtime's home on any backend.

    Raises:
        ValueError: naming the backend and the differing gains.
    """
    gains = [line for key, line in differences.items() if key in ("kp", "kd")]
    if gains and not sets_gains:
        raise ValueError(
            f"the policy was trained with other PD gains than robot.toml's "
            f"({'; '.join(gains)}); the {backend_name} backend cannot set its drives' "
            "gains: set kp, kd and control.home in robot.toml to the policy's values (or "
            "retrain)"
        )
