"""Policy export time and batch-1 inference latency: ONNX Runtime (OnnxPolicy) vs torch eager.

Run: ``.venv/bin/python -m bench.policy_inference [--calls 10000]``, or as the ``inference``
item of ``python -m bench``.

An arm3-sized MLP (every observation block of ``BLOCKS``, hidden [64, 64] ELU, act 3, with an
observation normalizer) is saved as our checkpoint and exported with ``policy-export``'s code
path (parity gate included); the export wall time is reported for the first export in the process
(cold: imports and first trace) and for a second one (warm). Inference: median and 99th percentile
of ``calls`` batch-1 calls after a warm-up, timed one by one with ``time.perf_counter_ns``, the
garbage collector frozen:
    - ``OnnxPolicy``: single-threaded session, IOBinding to preallocated buffers (the runtime);
    - ``session.run``: the same session through the plain ``run`` API (allocates per call);
    - torch eager: the same graph module (normalizer, MLP, action clip) under
      ``torch.inference_mode()``, with torch's default thread count and with 1 thread.
"""

from __future__ import annotations

import argparse
import gc
import os
import platform
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

os.environ.setdefault("ORT_DISABLE_TELEMETRY", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from sim2real.deploy.export import load_source, run_export  # noqa: E402
from sim2real.deploy.policy.mlp_checkpoint import MLPActor, save_checkpoint  # noqa: E402
from sim2real.deploy.policy.obs_normalizer import ObservationNormalizer  # noqa: E402
from sim2real.deploy.policy.onnx_policy import OnnxPolicy  # noqa: E402
from sim2real.deploy.spec.kinds import kind_names  # noqa: E402
from sim2real.deploy.spec.policy_spec import PolicySpec  # noqa: E402
from sim2real.robots import load_robot  # noqa: E402

#: Every observation block a fixed-base robot without wrapping joints has (arm3, arm6).
BLOCKS = tuple(
    k
    for k in kind_names(needs_base=False)
    if k not in ("joint_position_sincos", "joint_position_zero")
)


def time_calls(fn: Callable[[], object], calls: int, warmup: int = 500) -> np.ndarray:
    """Per-call wall time, us, of ``calls`` calls after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    out = np.empty(calls, dtype=np.int64)
    gc.collect()
    gc.freeze()
    gc.disable()
    try:
        for i in range(calls):
            t = time.perf_counter_ns()
            fn()
            out[i] = time.perf_counter_ns() - t
    finally:
        gc.enable()
        gc.unfreeze()
    return out / 1e3


def measure(calls: int = 10_000) -> dict:
    """Export timings and batch-1 inference latencies (see the module docstring).

    Returns:
        The ``inference`` entry of results.json: ``{"policy", "exports": [{"name", "seconds",
        "parity"}], "max_abs_error", "calls", "rows": [{"name", "median_us", "p99_us"}]}``.
    """
    robot = load_robot("arm3")
    spec = PolicySpec.for_robot(robot, blocks=BLOCKS)
    rng = np.random.default_rng(0)
    torch.manual_seed(0)
    actor = MLPActor(spec.obs_dim, spec.act_dim, hidden=(64, 64), activation="elu")
    norm = ObservationNormalizer(
        rng.normal(0, 0.1, spec.obs_dim), rng.uniform(0.5, 2, spec.obs_dim)
    )
    rows = []
    threads = torch.get_num_threads()
    with tempfile.TemporaryDirectory() as tmp:
        src = save_checkpoint(Path(tmp) / "arm.pt", actor, spec, norm)
        exports = []
        for name in ("cold", "warm"):
            t = time.perf_counter()
            result = run_export(src, out=Path(tmp) / f"arm_{name}.onnx")
            exports.append(
                {"name": name, "seconds": time.perf_counter() - t, "parity": result.parity}
            )
        policy = OnnxPolicy(result.path, robot)
        module = load_source(src).module()
        obs = rng.uniform(-1, 1, (1, spec.obs_dim)).astype(np.float32)
        obs_t = torch.from_numpy(obs)

        def torch_call() -> None:
            with torch.inference_mode():
                module(obs_t)

        feed = {policy.input_name: obs}
        rows.append(("OnnxPolicy (IOBinding, 1 thread)", time_calls(lambda: policy(obs), calls)))
        rows.append(
            ("onnxruntime session.run", time_calls(lambda: policy.session.run(None, feed), calls))
        )
        rows.append((f"torch eager ({threads} threads)", time_calls(torch_call, calls)))
        torch.set_num_threads(1)
        try:
            rows.append(("torch eager (1 thread)", time_calls(torch_call, calls)))
        finally:
            torch.set_num_threads(threads)
        with torch.inference_mode():
            err = float(np.abs(policy(obs) - module(obs_t).numpy()).max())
    return {
        "policy": "arm3, obs 21 -> [64, 64] ELU -> act 3, normalizer + action clip baked",
        "exports": exports,
        "max_abs_error": err,
        "calls": calls,
        "rows": [
            {
                "name": name,
                "median_us": float(np.median(us)),
                "p99_us": float(np.percentile(us, 99)),
            }
            for name, us in rows
        ],
    }


def print_report(r: dict) -> None:
    """Print a :func:`measure` result as text."""
    print(f"policy: {r['policy']}")
    for e in r["exports"]:
        f = e["parity"]
        print(
            f"export ({e['name']}): {e['seconds']:.2f} s wall (parity {f['max_abs_error']:.1e} "
            f"over {f['samples']} obs, {f['replay_max_abs_error']:.1e} over "
            f"{f['replay_ticks']} ticks)"
        )
    print(
        f"batch-1 inference, {r['calls']} calls each (|onnx - torch| = {r['max_abs_error']:.1e}):"
    )
    print(f"  {'':36} {'median us':>10} {'p99 us':>8}")
    for row in r["rows"]:
        print(f"  {row['name']:36} {row['median_us']:10.1f} {row['p99_us']:8.1f}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.policy_inference", description=__doc__)
    p.add_argument("--calls", type=int, default=10_000)
    args = p.parse_args(argv)
    r = measure(args.calls)
    print(
        f"{platform.platform()}, python {platform.python_version()}, torch {torch.__version__}, "
        f"onnxruntime {__import__('onnxruntime').__version__}, {os.cpu_count()} CPUs"
    )
    print_report(r)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
