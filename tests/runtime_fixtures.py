"""Small ONNX policies and a recording backend for the runtime tests."""

from __future__ import annotations

import numpy as np
import onnx

from deploy.adversarial import adversarial_model
from deploy.spec import PolicySpec


def adversarial_onnx(tmp_path, robot, mode, nan_probability=0.0, name="adv.onnx"):
    spec = PolicySpec.for_robot(robot, mode=mode)
    path = tmp_path / f"{robot.name}_{mode}_{name}"
    onnx.save(adversarial_model(spec, nan_probability), path)
    return path


class Recorder:
    """Wraps a backend and keeps every command written to it, shape (ticks, envs, n)."""

    def __init__(self, backend):
        self.backend = backend
        self.commands = []
        self.true_q = []

    def __getattr__(self, name):
        return getattr(self.backend, name)

    def write(self, command):
        assert np.isfinite(command).all(), "a non-finite command reached the backend"
        self.commands.append(np.array(command, copy=True))
        self.backend.write(command)

    def advance(self):
        self.backend.advance()
        self.true_q.append(self.backend.true_position().copy())
