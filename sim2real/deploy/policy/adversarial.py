"""An adversarial policy: the worst a network can send, as an ONNX file with our contract.

Two kinds, each with NaN with probability ``nan_probability`` per call and env:

- ``uniform``: uniform random actions in ``[-1, 1]``, a new draw every call;
- ``saturating``: ``sign(W obs + b)``, a fixed random linear map of the observation driven into
  saturation (every action component +-1): a deterministic feedback law that pins the robot
  against its limits and swings it between corners, as a diverged network does.

Run it through the runtime to show that whatever a policy outputs, no command beyond the hard
position limits or the velocity, acceleration and jerk limits reaches the robot::

    python -m sim2real.deploy.policy.adversarial --robot arm3 --mode velocity --out /tmp/adversarial.onnx
    deploy-run --robot arm3 --policy /tmp/adversarial.onnx --duration 600 \\
        --inject nan-action@30:0.2

The graph is built with ``onnx.helper`` (no torch): ``RandomUniformLike`` ops on an
(batch, act_dim) tensor derived from the observation, so the batch axis stays dynamic.
"""

from __future__ import annotations

import argparse
import hashlib
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper

from sim2real.deploy.spec.policy_spec import PolicySpec
from sim2real.robots import CONTROL_MODES, load_robot
from sim2real.robots.files import atomic_path

OPSET = 18  # ReduceMin takes its axes as an input from opset 18


KINDS = ("uniform", "saturating")


def adversarial_model(
    spec: PolicySpec, nan_probability: float = 0.02, seed: float = 0.0, kind: str = "uniform"
):
    """ONNX model (``onnx.ModelProto``) of the adversarial policy for ``spec``.

    Input ``obs`` float32 (batch, spec.obs_dim); output ``action`` float32 (batch, spec.act_dim).
    The spec JSON is stored in the metadata under ``policy_spec``. The random streams are seeded;
    the NaN stream's seed is the first from ``seed + 1`` whose first answer is finite, because
    :class:`~sim2real.deploy.policy.onnx_policy.OnnxPolicy` probes a policy once with a zero observation and
    refuses a non-finite answer. ``kind``: one of :data:`KINDS` (module docstring); the saturating
    map's weights are standard normal draws from ``numpy.random.default_rng(seed)``.

    Raises:
        ValueError: an unknown ``kind``.
    """
    import onnxruntime as ort

    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")

    nan_seed = _first_finite_nan_seed(spec.act_dim, nan_probability, seed + 1.0)
    model = _build(spec, nan_probability, seed, nan_seed, kind)
    session = ort.InferenceSession(model.SerializeToString())
    first = session.run(None, {"obs": np.zeros((1, spec.obs_dim), np.float32)})[0]
    if not np.isfinite(first).all():  # the probe below and the model disagree: never expected
        raise RuntimeError(f"the adversarial policy's first answer is not finite ({nan_seed=})")
    return model


#: NaN-stream seeds tried per probe session in :func:`_first_finite_nan_seed`.
PROBE_SEEDS = 256


def _first_finite_nan_seed(n: int, nan_probability: float, start: float) -> float:
    """The first seed from ``start`` (in steps of 1) whose NaN stream answers finite on the first
    call of ``n`` actions: the same seed as building the whole model for every candidate and
    probing it, but :data:`PROBE_SEEDS` candidates per ONNX Runtime session (each
    ``RandomUniformLike`` node draws from a generator of its own seed). ORT's generator makes the
    first draws of small seeds tiny (about ``seed * 7.8e-6``), so the search runs to a seed of
    about ``1 - (1 - p)**(1/n)`` over 7.8e-6: hundreds to thousands of candidates."""
    import onnxruntime as ort

    threshold = 1.0 - (1.0 - nan_probability) ** (1.0 / n)
    inits = [
        helper.make_tensor("ax1", TensorProto.INT64, [1], [1]),
        helper.make_tensor("nan_p", TensorProto.FLOAT, [], [threshold]),
    ]
    like = {"like": np.zeros((1, n), np.float32)}
    while True:
        nodes = []
        for k in range(PROBE_SEEDS):  # the nodes of _build's NaN stream, once per candidate
            nodes += [
                helper.make_node(
                    "RandomUniformLike", ["like"], [f"p{k}"], low=0.0, high=1.0, seed=start + k
                ),
                helper.make_node("ReduceMin", [f"p{k}", "ax1"], [f"pmin{k}"], keepdims=1),
                helper.make_node("Less", [f"pmin{k}", "nan_p"], [f"bad{k}"]),
            ]
        nodes.append(
            helper.make_node("Concat", [f"bad{k}" for k in range(PROBE_SEEDS)], ["bad"], axis=1)
        )
        graph = helper.make_graph(
            nodes,
            "nan_seed_probe",
            [helper.make_tensor_value_info("like", TensorProto.FLOAT, [1, n])],
            [helper.make_tensor_value_info("bad", TensorProto.BOOL, [1, PROBE_SEEDS])],
            initializer=inits,
        )
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
        model.ir_version = 8
        bad = ort.InferenceSession(model.SerializeToString()).run(None, like)[0][0]
        finite = np.flatnonzero(~bad)
        if len(finite):
            return start + float(finite[0])
        start += PROBE_SEEDS


def _build(spec: PolicySpec, nan_probability: float, seed: float, nan_seed: float, kind: str):
    n, d = spec.act_dim, spec.obs_dim
    rng = np.random.default_rng(int(seed))
    if kind == "saturating":  # u = sign(obs @ W + b)
        source = [
            helper.make_node("MatMul", ["obs", "W"], ["wx"]),
            helper.make_node("Add", ["wx", "b"], ["pre"]),
            helper.make_node("Sign", ["pre"], ["u"]),
        ]
    else:
        source = [
            helper.make_node("RandomUniformLike", ["like"], ["u"], low=-1.0, high=1.0, seed=seed)
        ]
    nodes = [
        # (batch, n) zeros shaped like the action: obs[:, :1] * zeros(1, n)
        helper.make_node("Slice", ["obs", "s0", "s1", "ax1"], ["first"]),
        helper.make_node("Mul", ["first", "zeros_n"], ["like"]),
        *source,
        helper.make_node("RandomUniformLike", ["like"], ["p"], low=0.0, high=1.0, seed=nan_seed),
        helper.make_node("ReduceMin", ["p", "ax1"], ["pmin"], keepdims=1),
        helper.make_node("Less", ["pmin", "nan_p"], ["bad"]),
        # NaN computed at run time (0 / 0): the file holds only finite weights, so it passes the
        # loader's non-finite-weight check like any real policy would
        helper.make_node("Div", ["like", "like"], ["nan"]),
        helper.make_node("Where", ["bad", "nan", "u"], ["action"]),
    ]
    inits = [
        helper.make_tensor("s0", TensorProto.INT64, [1], [0]),
        helper.make_tensor("s1", TensorProto.INT64, [1], [1]),
        helper.make_tensor("ax1", TensorProto.INT64, [1], [1]),
        helper.make_tensor("zeros_n", TensorProto.FLOAT, [1, n], np.zeros(n)),
        # per env: NaN with probability nan_probability (min of n uniforms below 1-(1-p)^(1/n))
        helper.make_tensor(
            "nan_p", TensorProto.FLOAT, [], [1.0 - (1.0 - nan_probability) ** (1.0 / n)]
        ),
    ]
    if kind == "saturating":
        inits += [
            helper.make_tensor("W", TensorProto.FLOAT, [d, n], rng.standard_normal((d, n))),
            helper.make_tensor("b", TensorProto.FLOAT, [n], 0.1 * rng.standard_normal(n)),
        ]
    graph = helper.make_graph(
        nodes,
        "adversarial_policy",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["batch", d])],
        [helper.make_tensor_value_info("action", TensorProto.FLOAT, ["batch", n])],
        initializer=inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)])
    model.ir_version = 8
    spec_json = spec.to_json()
    helper.set_model_props(
        model,
        {
            "policy_spec": spec_json,
            "source_sha256": hashlib.sha256(spec_json.encode()).hexdigest(),
            "adversarial": f"{kind} actions in [-1, 1] with NaN",
        },
    )
    onnx.checker.check_model(model)
    return model


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m sim2real.deploy.policy.adversarial",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--robot", default="arm3")
    p.add_argument("--mode", choices=CONTROL_MODES, default=None)
    p.add_argument("--kind", choices=KINDS, default="uniform")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--nan-probability", type=float, default=0.02)
    p.add_argument("--out", type=Path, required=True)
    args = p.parse_args(argv)
    robot = load_robot(args.robot)
    spec = PolicySpec.for_robot(robot, mode=args.mode, position_range="hard")
    model = adversarial_model(spec, args.nan_probability, float(args.seed), args.kind)
    with atomic_path(args.out) as tmp:
        onnx.save(model, tmp)
    print(f"wrote {args.out}: adversarial ({args.kind}) {spec.action.mode} policy for {robot.name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
