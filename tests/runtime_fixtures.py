"""Small ONNX policies for the runtime tests."""

from __future__ import annotations

import onnx

from deploy.adversarial import adversarial_model
from deploy.spec import PolicySpec


def adversarial_onnx(tmp_path, robot, mode, nan_probability=0.0, name="adv.onnx"):
    spec = PolicySpec.for_robot(robot, mode=mode)
    path = tmp_path / f"{robot.name}_{mode}_{name}"
    onnx.save(adversarial_model(spec, nan_probability), path)
    return path
