"""The Diffusion Policy part of a LeRobot ``config.json`` (``type`` ``diffusion``), read without
lerobot (:func:`read_diffusion`) for :func:`sim2real.deploy.spec.foreign.lerobot.read`.

The fields are ``DiffusionConfig``'s (``lerobot/policies/diffusion/configuration_diffusion.py``,
lerobot 0.4.4): ``n_obs_steps`` (default 2), ``horizon`` (16), ``n_action_steps`` (8),
``noise_scheduler_type`` (``DDPM``/``DDIM``), ``num_train_timesteps`` (100),
``num_inference_steps`` (None: ``num_train_timesteps``, ``DiffusionModel.__init__``),
``beta_schedule``, ``prediction_type`` (``epsilon``/``sample``), ``clip_sample``,
``clip_sample_range``, the image path (``vision_backbone``, ``pretrained_backbone_weights``,
``resize_shape``, ``crop_shape``, ``use_group_norm``) and ``down_dims`` (the U-Net's
downsampling: ``horizon`` must be a multiple of ``2 ** len(down_dims)``). ``select_action``
executes ``n_action_steps`` actions from index ``n_obs_steps - 1`` of the ``horizon``
generated (``DiffusionModel.generate_actions``), so ``n_action_steps <= horizon - n_obs_steps +
1`` (the class docstring of ``DiffusionPolicy.select_action``).

What the export does not build is refused here in one line naming the field and the value
expected: a pretrained backbone (torchvision downloads its weights), ``resize_shape`` (a
torchvision ``Resize`` the graph does not carry), ``compile_model`` true, a scheduler or a
prediction type lerobot 0.4.4 does not have.
"""

from __future__ import annotations

from pathlib import Path

from sim2real.deploy.spec.foreign.lerobot_contract import LeRobotFormatError

SCHEDULERS = ("DDPM", "DDIM")
PREDICTION_TYPES = ("epsilon", "sample")


def _int(cfg: dict, name: str, path: Path, default=None, low: int = 1) -> int:
    v = cfg.get(name, default)
    if isinstance(v, bool) or not isinstance(v, int) or v < low:
        raise LeRobotFormatError(f"{path}: {name} must be an integer >= {low}, got {v!r}")
    return v


def read_diffusion(cfg: dict, path: Path, cameras, env_state_dim: int) -> dict:
    """Diffusion Policy's fields of ``cfg`` (``config.json`` at ``path``).

    Args:
        cfg: The parsed ``config.json``. path: It, for the messages.
        cameras: ``(key, (3, H, W))`` per camera, as the reader found them.
        env_state_dim: Entries of ``observation.environment_state`` (0: none).

    Returns:
        ``{"n_obs_steps", "horizon", "n_action_steps", "diffusion"}``; ``diffusion`` as
        :attr:`LeRobotContract.diffusion` without the export's ``timesteps`` and
        ``noise_inputs``.

    Raises:
        LeRobotFormatError: A field missing, of the wrong type or value, or not supported (module
            docstring), in one line naming ``path`` and the field.
    """
    n_obs = _int(cfg, "n_obs_steps", path)
    horizon = _int(cfg, "horizon", path)
    n_act = _int(cfg, "n_action_steps", path)
    if n_act > horizon - n_obs + 1:
        raise LeRobotFormatError(
            f"{path}: n_action_steps {n_act} exceeds horizon - n_obs_steps + 1 = "
            f"{horizon - n_obs + 1} (DiffusionPolicy.select_action)"
        )
    down = cfg.get("down_dims")
    if not isinstance(down, list) or not down:
        raise LeRobotFormatError(f"{path}: down_dims must be a list of integers, got {down!r}")
    if horizon % 2 ** len(down):
        raise LeRobotFormatError(
            f"{path}: horizon {horizon} must be a multiple of 2 ** len(down_dims) = "
            f"{2 ** len(down)}"
        )
    if not cameras and not env_state_dim:
        raise LeRobotFormatError(
            f"{path}: input_features needs a camera or observation.environment_state "
            "(DiffusionConfig.validate_features)"
        )
    sched = cfg.get("noise_scheduler_type")
    if sched not in SCHEDULERS:
        raise LeRobotFormatError(
            f"{path}: noise_scheduler_type {sched!r} is not read (expected one of "
            f"{', '.join(SCHEDULERS)})"
        )
    pred = cfg.get("prediction_type")
    if pred not in PREDICTION_TYPES:
        raise LeRobotFormatError(
            f"{path}: prediction_type {pred!r} is not read (expected one of "
            f"{', '.join(PREDICTION_TYPES)})"
        )
    train_steps = _int(cfg, "num_train_timesteps", path)
    steps = cfg.get("num_inference_steps")
    steps = train_steps if steps is None else _int(cfg, "num_inference_steps", path)
    if steps > train_steps:
        raise LeRobotFormatError(
            f"{path}: num_inference_steps {steps} exceeds num_train_timesteps {train_steps}"
        )
    if cfg.get("pretrained_backbone_weights") is not None:
        raise LeRobotFormatError(
            f"{path}: pretrained_backbone_weights {cfg['pretrained_backbone_weights']!r} is not "
            "read (torchvision downloads them; expected null: the folder's own weights)"
        )
    if cfg.get("resize_shape") is not None:
        raise LeRobotFormatError(
            f"{path}: resize_shape {cfg['resize_shape']!r} is not read (expected null: feed the "
            "images at the features' shape)"
        )
    if cfg.get("compile_model"):
        raise LeRobotFormatError(f"{path}: compile_model true is not read (expected false)")
    backbone = cfg.get("vision_backbone", "resnet18")
    if cameras and not (isinstance(backbone, str) and backbone.startswith("resnet")):
        raise LeRobotFormatError(
            f"{path}: vision_backbone {backbone!r} is not read (expected a torchvision resnet)"
        )
    crop = cfg.get("crop_shape")
    if crop is not None:
        ok = (
            isinstance(crop, list)
            and len(crop) == 2
            and all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in crop)
        )
        if not ok:
            raise LeRobotFormatError(
                f"{path}: crop_shape must be null or [rows, columns], got {crop!r}"
            )
        for key, shape in cameras:
            if crop[0] > shape[1] or crop[1] > shape[2]:
                raise LeRobotFormatError(
                    f"{path}: crop_shape {crop} exceeds {key}'s {shape[1]} x {shape[2]}"
                )
    shapes = {shape for _, shape in cameras}
    if len(shapes) > 1:
        raise LeRobotFormatError(
            f"{path}: input_features' cameras differ in shape {sorted(shapes)}; Diffusion Policy "
            "takes one shape (DiffusionConfig.validate_features)"
        )
    clip_range = cfg.get("clip_sample_range", 1.0)
    if isinstance(clip_range, bool) or not isinstance(clip_range, (int, float)) or clip_range <= 0:
        raise LeRobotFormatError(
            f"{path}: clip_sample_range must be a number above 0, got {clip_range!r}"
        )
    return {
        "n_obs_steps": n_obs,
        "horizon": horizon,
        "n_action_steps": n_act,
        "diffusion": {
            "scheduler": sched,
            "num_train_timesteps": train_steps,
            "num_inference_steps": steps,
            "beta_schedule": cfg.get("beta_schedule"),
            "prediction_type": pred,
            "clip_sample": bool(cfg.get("clip_sample", True)),
            "clip_sample_range": float(clip_range),
            "crop_shape": None if crop is None else [int(crop[0]), int(crop[1])],
        },
    }
