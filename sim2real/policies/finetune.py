"""Fine-tuning a shipped policy: its actor copied into a fresh PPO learner, and a critic warm-up.

A shipped checkpoint (:func:`~sim2real.deploy.policy.mlp_checkpoint.save_checkpoint`) keeps the actor only.
:func:`load_shipped_actor` writes it into PPO's Gaussian mean (``mlp_extractor.policy_net`` and
``action_net``; the reverse of :func:`sim2real.deploy.export.sb3_actor`); the critic and the noise keep their
fresh initialization. :func:`learn_with_critic_warmup` then trains the critic alone for a number
of steps, with the actor and its noise frozen, so that a random critic's advantages do not move the
shipped actor before the critic has learnt its returns.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import torch
from stable_baselines3 import PPO

from sim2real.deploy.policy.mlp_checkpoint import load_checkpoint


def load_shipped_actor(model: PPO, checkpoint: Path, spec, hidden: tuple[int, ...]) -> None:
    """Start ``model``'s Gaussian mean from a checkpoint's actor.

    Args:
        model: a PPO learner whose ``net_arch["pi"]`` is ``hidden``.
        checkpoint: a shipped ``.pt`` (``sim2real/policies/go2.pt``, ``sim2real/policies/arm.pt``...).
        spec: the recipe's :class:`~sim2real.deploy.policy.spec.PolicySpec`; the checkpoint's must equal
            it, or differ only in the action's scale and offset (:func:`action_remap`: the output
            layer is then rescaled so that the mean gives the same targets), or lack only its
            last block, a ``height_scan`` (:func:`scan_columns`: the scan's input weights start
            at 0, so the actor acts as the checkpoint's until training moves them).
        hidden: the recipe's hidden layer widths.

    Raises:
        ValueError: the checkpoint's spec is not ``spec``'s (beyond the action's scale and
            offset), or its hidden layers are not ``hidden`` (the file and the expected value
            named).
    """
    actor, source, _ = load_checkpoint(checkpoint)
    scan = scan_columns(source, spec)
    if scan:  # the recipe's spec is the checkpoint's plus a height scan: its columns start at 0
        source = spec
    same = source.to_json() == spec.to_json()
    remap = None if same else action_remap(source, spec)
    if not same and remap is None:
        raise ValueError(
            f"{checkpoint}: --init-from expected a checkpoint of this recipe's spec (robot "
            f"{spec.robot}, obs {spec.obs_dim}, act {spec.act_dim}); its spec differs"
        )
    layers = [m for m in actor.net if isinstance(m, torch.nn.Linear)]
    policy = model.policy
    targets = [m for m in policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
    targets.append(policy.action_net)
    widths = tuple(m.out_features for m in layers[:-1])
    if widths != tuple(hidden):
        raise ValueError(f"{checkpoint}: hidden layers {widths}, expected {tuple(hidden)}")
    with torch.no_grad():
        for source_layer, target in zip(layers, targets, strict=True):
            if scan and target is targets[0]:  # the scan's inputs weigh 0 at the start
                target.weight.zero_()
                target.weight[:, : target.in_features - scan].copy_(source_layer.weight)
            else:
                target.weight.copy_(source_layer.weight)
            target.bias.copy_(source_layer.bias)
        if remap is not None:  # the same targets under the recipe's action scale and offset
            gain, shift = (torch.as_tensor(v, dtype=policy.action_net.weight.dtype) for v in remap)
            policy.action_net.weight.mul_(gain[:, None])
            policy.action_net.bias.mul_(gain).add_(shift)


def scan_columns(source, spec) -> int:
    """The entries of ``spec``'s ``height_scan`` block when ``spec`` is ``source`` with that
    block appended (:func:`sim2real.deploy.export.scan_input.with_height_scan`: a blind
    checkpoint fine-tuned into a perceptive policy), else 0."""
    blocks = spec.observation_blocks
    if not blocks or blocks[-1].name != "height_scan":
        return 0
    blind = dataclasses.replace(spec, observation_blocks=blocks[:-1])
    return blocks[-1].size if blind.to_json() == source.to_json() else 0


def action_remap(source, spec) -> tuple[np.ndarray, np.ndarray] | None:
    """Per-joint ``(gain, shift)`` with ``gain * a + shift`` the action under ``spec`` that gives
    the target action ``a`` gives under ``source``, both (act_dim,); ``None`` unless the two
    specs differ only in the action's scale and offset (the same robot, observation layout,
    mode, reference and clip). A fine-tune of a policy trained when a full absolute position
    action was the hard limit (``position_range="hard"``) starts from the same targets under
    today's soft range; a target it reached past the new full action is then clipped to it.
    """
    a, b = source.action, spec.action
    aligned = dataclasses.replace(
        source, action=dataclasses.replace(a, scale=b.scale, offset=b.offset)
    )
    if aligned.to_json() != spec.to_json() or a.reference == "current":
        return None
    s_old, o_old = np.asarray(a.scale), np.asarray(a.offset)
    s_new, o_new = np.asarray(b.scale), np.asarray(b.offset)
    return s_old / s_new, (o_old - o_new) / s_new


def actor_parameters(model: PPO) -> list[torch.nn.Parameter]:
    """The parameters of ``model``'s actor: its mean network and its log standard deviation."""
    policy = model.policy
    return [
        *policy.mlp_extractor.policy_net.parameters(),
        *policy.action_net.parameters(),
        policy.log_std,
    ]


def learn_with_critic_warmup(model: PPO, steps: int, warmup: int, **learn_kwargs) -> None:
    """``model.learn(steps)``, of which the first ``min(warmup, steps)`` environment steps train
    the critic alone (every actor parameter frozen); ``learn_kwargs`` go to both ``learn`` calls
    (``callback``, ``tb_log_name``, ``progress_bar``). The step count runs on across the two."""
    warmup = min(warmup, steps)
    if warmup:
        for parameter in actor_parameters(model):
            parameter.requires_grad_(False)
        model.learn(warmup, **learn_kwargs)
        for parameter in actor_parameters(model):
            parameter.requires_grad_(True)
    model.learn(steps - warmup, reset_num_timesteps=not warmup, **learn_kwargs)


def add_finetune_arguments(p: argparse.ArgumentParser, shipped: str) -> None:
    """``--init-from`` (``args.init_from``: a saved run's ``.zip`` to continue, or a shipped
    ``.pt`` such as ``shipped`` to fine-tune) and ``--critic-warmup`` (``args.critic_warmup``,
    environment steps)."""
    p.add_argument(
        "--init-from",
        type=Path,
        default=None,
        metavar="RUN.zip|POLICY.pt",
        help="continue training a saved learner (the .zip beside a candidate), or fine-tune a "
        f"shipped policy ({shipped}: its actor, with a fresh critic)",
    )
    p.add_argument(
        "--critic-warmup",
        type=int,
        default=0,
        metavar="STEPS",
        help="first train the critic alone for STEPS steps (the actor frozen)",
    )
