"""What a camera costs and how wrong it is: the Go2 with a head camera (the way a user
adds one: a ``<camera>`` on the base in a copy of the robot's folder, :func:`head_camera_robot`),
MuJoCo's offscreen depth render per frame at Extreme Parkour's 60 x 106 and at 240 x 424, its
arm3's task scene as the shipped camera policy sees it (``goal_camera``, 96 x 72 depth), its
colour render at 96 x 128 and at LeRobot's 480 x 640 (with shadows, as
:class:`~sim2real.deploy.backends.sim.rgb_render.RgbRenderer` draws it) and the colour sensor
model (OV5647 noise, drift, uint8) per frame, the depth model's error on a flat target 1 m and
2 m ahead against the D435 datasheet's bound (RMS <= 2 % at 2 m), and the image preprocessing
per frame (depth 60 x 106 -> 58 x 87; RGB 480 x 640 -> 96 x 128 CHW).

Usage::

    MUJOCO_GL=egl python -m bench.camera_cost [--frames 200] [--out DIR]

Prints one line per figure (render: us, p50 and p99; error: mm and % of the distance); the render
cost is a figure of this machine's GL (Mesa's llvmpipe where there is no GPU), not a test.
"""

from __future__ import annotations

import argparse
import re
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from sim2real.deploy.backends.sim.camera import D435_AT, D435_RMS

#: The head camera on the Go2's base: just ahead of the base box's front face (x 0.346 m), 3 cm
#: above the base origin (Extreme Parkour's front camera: [0.27, 0, 0.03] on the A1), looking
#: ahead (MuJoCo cameras look along their -z; x right is the base's -y, y up its +z), vertical
#: field of view 58 deg (the D435's depth field of view, 87 x 58 deg).
HEAD_CAMERA = '<camera name="head_depth" pos="0.36 0 0.03" xyaxes="0 -1 0 0 0 1" fovy="58"/>'


def head_camera_robot(out: Path, target: float | None = None) -> Path:
    """A copy of the shipped Go2's folder in ``out`` with :data:`HEAD_CAMERA` on its base and,
    when ``target`` is given, a flat box that far ahead of the camera, m (2 m high, 6 m wide);
    the folder's path (``load_robot`` reads it)."""
    from sim2real.robots.loading import ROBOTS_DIR

    out.mkdir(parents=True, exist_ok=True)
    for f in ("robot.toml", "go2.xml"):
        shutil.copy(Path(ROBOTS_DIR) / "go2" / f, out / f)
    xml = (out / "go2.xml").read_text()
    xml = re.sub(r'(<site name="imu"[^>]*/>)', r"\1\n      " + HEAD_CAMERA, xml, count=1)
    if target is not None:
        x = 0.36 + target + 0.05  # the box's near face `target` m ahead of the camera
        geom = f'<geom name="wall" type="box" size="0.05 3 1" pos="{x:.4f} 0 1"/>'
        xml = xml.replace('<light name="sun"', geom + '\n    <light name="sun"', 1)
    (out / "go2.xml").write_text(xml)
    return out


def depth_costs(camera, frames: int) -> np.ndarray:
    """(frames,) ns, one render of ``camera``'s true depth each (after one to warm); closes it."""
    camera.true_depth()  # warm
    costs = []
    for _ in range(frames):
        t0 = time.perf_counter_ns()
        camera.true_depth()
        costs.append(time.perf_counter_ns() - t0)
    camera.close()
    return np.asarray(costs, dtype=np.int64)


def render_costs(robot, block, frames: int) -> np.ndarray:
    """(frames,) ns, one render of the head camera's true depth (the robot standing)."""
    from sim2real.deploy.backends.sim.camera import PlantDepthCamera
    from sim2real.deploy.backends.sim.plant import SimBackend

    plant = SimBackend(robot, "position", envs=1)
    camera = PlantDepthCamera(plant, block)
    return depth_costs(camera, frames)


def task_scene_costs(frames: int) -> np.ndarray:
    """(frames,) ns, one render of arm3's task scene by the shipped camera policy's own block
    (``arm_camera.onnx``: ``goal_camera``, 96 x 72 depth, a camera outside the robot's MJCF, so
    rendered from robot.toml's ``[task] scene``, its goal marker shown), as
    :func:`~sim2real.deploy.backends.sim.camera.attach_plant_camera` builds it for deploy-run."""
    import sim2real.policies
    from sim2real.deploy.backends.sim.camera import attach_plant_camera
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.policy.onnx_policy import OnnxPolicy
    from sim2real.robots import load_robot

    robot = load_robot("arm3")
    shipped = Path(sim2real.policies.__file__).parent / "arm_camera.onnx"
    spec = OnnxPolicy(shipped, robot).spec
    plant = SimBackend(robot, spec.action.mode, envs=1)
    camera = attach_plant_camera(plant, spec)
    return depth_costs(camera, frames)


def rgb_costs(robot, block, frames: int) -> tuple[np.ndarray, np.ndarray]:
    """(frames,) ns each: one colour render of the head camera (no sensor model), and the
    sensor model as a frame meets it (:meth:`~sim2real.deploy.backends.sim.rgb_camera.
    PlantRgbCamera.sensor`: OV5647 noise, drift, uint8)."""
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.backends.sim.rgb_camera import PlantRgbCamera

    plant = SimBackend(robot, "position", envs=1)
    camera = PlantRgbCamera(plant, block)
    image = camera.true_image().copy()  # warm
    camera.sensor(0, image, camera.rng)  # its pool of normal draws made
    render, sensor = [], []
    for _ in range(frames):
        t0 = time.perf_counter_ns()
        camera.true_image()
        t1 = time.perf_counter_ns()
        camera.sensor(0, image, camera.rng)
        sensor.append(time.perf_counter_ns() - t1)
        render.append(t1 - t0)
    camera.close()
    return np.asarray(render, dtype=np.int64), np.asarray(sensor, dtype=np.int64)


def wall_errors(out: Path, frames: int) -> dict[float, dict]:
    """The D435 model's depth error on a flat target 1 m and 2 m ahead of the head camera."""
    from sim2real.deploy.backends.sim.camera import PlantDepthCamera, depth_error
    from sim2real.deploy.backends.sim.plant import SimBackend
    from sim2real.deploy.spec.camera import DepthImageBlock
    from sim2real.robots import load_robot

    block = DepthImageBlock(camera="head_depth")
    rows = {}
    for at in (1.0, 2.0):
        robot = load_robot(head_camera_robot(out / f"wall_{at:g}", target=at))
        plant = SimBackend(robot, "position", envs=1)
        camera = PlantDepthCamera(plant, block, seed=0)
        rows[at] = depth_error(camera, frames, at)
        camera.close()
    return rows


def measure(out: Path, frames: int) -> dict:
    """The ``camera`` entry of results.json: ``{"frames", "rows": [{what, p50_us, p99_us,
    p99.9_us, max_us, mean_us, samples}], "errors": [{at_m, pixels, rms_mm, rms_percent,
    datasheet_percent, invalid_percent}]}``; ``{"skipped": why}`` without an OpenGL context."""
    from sim2real.deploy.spec.camera import DepthImageBlock, RgbImageBlock, preprocess
    from sim2real.robots import load_robot

    robot = load_robot(head_camera_robot(out / "go2_head"))
    small = DepthImageBlock(camera="head_depth")
    large = DepthImageBlock(camera="head_depth", shape=(240, 424), crop=(0, 0, 0, 0))
    rgb_small = RgbImageBlock(camera="head_depth", shape=(96, 128), resize=(96, 128))
    rgb_large = RgbImageBlock(camera="head_depth", resize=(96, 128))  # LeRobot's 480 x 640
    try:
        timings = {
            "render 60 x 106 (Extreme Parkour)": render_costs(robot, small, frames),
            "render 240 x 424": render_costs(robot, large, frames),
            "render arm3 task scene 96 x 72": task_scene_costs(frames),
        }
        for name, block in (("96 x 128", rgb_small), ("480 x 640 (LeRobot)", rgb_large)):
            render, sensor = rgb_costs(robot, block, frames)
            timings[f"render RGB {name}"] = render
            timings[f"RGB sensor model {name.split(' (')[0]}"] = sensor
    except RuntimeError as exc:  # no OpenGL context: the message names MUJOCO_GL
        return {"skipped": str(exc)}
    for name, block, frame in (
        ("preprocess 60 x 106 -> 58 x 87", small, np.full((1, *small.shape), 1.5, np.float32)),
        (
            "preprocess RGB 480 x 640 -> 96 x 128",
            rgb_large,
            np.full((1, *rgb_large.frame_shape), 128, np.uint8),
        ),
    ):
        costs = []
        for _ in range(frames):
            t0 = time.perf_counter_ns()
            preprocess(frame, block)
            costs.append(time.perf_counter_ns() - t0)
        timings[name] = np.asarray(costs, dtype=np.int64)
    rows = [{"what": k, **_percentiles(v)} for k, v in timings.items()]
    errors = [
        {
            "at_m": at,
            "pixels": e["pixels"],
            "rms_mm": round(1e3 * e["rms_m"], 2),
            "rms_percent": round(100 * e["rms_fraction"], 3),
            "datasheet_percent": 100 * D435_RMS if at == D435_AT else None,
            "invalid_percent": round(100 * e["invalid_fraction"], 2),
        }
        for at, e in wall_errors(out, max(frames // 10, 5)).items()
    ]
    return {"frames": frames, "rows": rows, "errors": errors}


def _percentiles(ns: np.ndarray) -> dict:
    """p50, p99, p99.9, max and mean (us) and the sample count of ``ns`` (int ns), from the
    samples themselves (the bench's latency histogram stops at ``BINS`` x ``BIN_NS``,
    :mod:`sim2real.deploy.core.latency`: a 640 x 480 colour render on a software renderer may
    take longer)."""
    us = np.asarray(ns, dtype=np.float64) / 1e3
    p50, p99, p999 = np.percentile(us, [50, 99, 99.9])
    return {
        "p50_us": float(p50),
        "p99_us": float(p99),
        "p99.9_us": float(p999),
        "max_us": float(us.max()),
        "mean_us": float(us.mean()),
        "samples": int(us.size),
    }


def render_lines(sec: dict, add) -> None:
    """The ``camera`` section of the bench's table (:func:`bench.render.render`)."""
    add(
        f"== camera: the Go2's head camera and arm3's task scene, MuJoCo offscreen depth and RGB (1 env), "
        f"{sec['frames']} frames; the D435 model's error on a wall (datasheet: RMS <= 2 % at 2 m)"
    )
    for r in sec["rows"]:
        add(f"{r['what']:36} p50 {r['p50_us']:>9.1f} us  p99 {r['p99_us']:>9.1f} us")
    for e in sec["errors"]:
        add(
            f"wall at {e['at_m']:g} m: RMS {e['rms_mm']:.1f} mm = {e['rms_percent']:.2f} % "
            f"({e['pixels']} px, invalid {e['invalid_percent']:.1f} %)"
        )


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    sec = measure(args.out or Path(tempfile.mkdtemp()), args.frames)
    if "skipped" in sec:
        print(f"camera: skipped: {sec['skipped']}")
        return
    render_lines(sec, print)


if __name__ == "__main__":
    main()
