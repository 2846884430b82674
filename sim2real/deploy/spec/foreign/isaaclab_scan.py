"""Isaac Lab's ``height_scan`` observation term read from a run's ``env.yaml``: the term's ``offset``
(``isaaclab.envs.mdp.observations.height_scan``, default 0.5 m) and its ``RayCaster`` sensor's grid
(``scene.<sensor_cfg.name>``: ``pattern_cfg`` a ``GridPatternCfg`` with ``resolution``, ``size``,
``ordering`` (default ``xy``) and ``direction`` (0, 0, -1); ``ray_alignment`` ``yaw``, ``base``
or ``world``, or an older release's ``attach_yaw_only``). The sensor's ``offset.pos`` moves the
rays' starts (20 m up in the velocity task), not the point the term measures from (the body's
``pos_w``): the pattern's ``sensor_offset`` is 0. Anything else is refused by name.
"""

from __future__ import annotations

from dataclasses import replace

from sim2real.deploy.spec.height_scan import HeightScanPattern

#: The function of the term (``module:name`` in env.yaml).
FUNCTION = "height_scan"
#: The term's default offset, m (``isaaclab.envs.mdp.observations.height_scan``).
DEFAULT_OFFSET = 0.5


def height_scan_term(term, cfg: dict, scene: dict):
    """``term`` (a :class:`~sim2real.deploy.spec.foreign.contract.Term` read without its sensor)
    with the kind ``height_scan``, its size, offset and scan; or with kind None and the reason
    where the sensor is not a downward grid this toolkit casts."""
    params = cfg.get("params") or {}
    sensor_name = (params.get("sensor_cfg") or {}).get("name", "height_scanner")
    sensor = (scene or {}).get(sensor_name)
    if not isinstance(sensor, dict):
        return replace(term, kind=None, reason=f"its sensor scene.{sensor_name} is not in env.yaml")
    pattern = sensor.get("pattern_cfg") or {}
    func = str(pattern.get("func", ""))
    if not func.endswith("grid_pattern") or "resolution" not in pattern or "size" not in pattern:
        return replace(
            term, kind=None, reason=f"scene.{sensor_name}.pattern_cfg is not a GridPatternCfg"
        )
    direction = [float(v) for v in pattern.get("direction", (0.0, 0.0, -1.0))]
    if direction != [0.0, 0.0, -1.0]:
        return replace(
            term, kind=None, reason=f"scene.{sensor_name} casts along {direction}, not down"
        )
    alignment = sensor.get("ray_alignment")
    if alignment is None:
        alignment = "yaw" if sensor.get("attach_yaw_only", True) else "base"
    if alignment not in ("yaw", "base", "world"):
        return replace(term, kind=None, reason=f"ray_alignment '{alignment}' is unknown")
    scan = HeightScanPattern.grid(
        float(pattern["resolution"]),
        tuple(float(v) for v in pattern["size"]),
        ordering=str(pattern.get("ordering", "xy")),
        alignment=str(alignment),
    )
    problems = scan.problems(f"scene.{sensor_name}")
    if problems:
        return replace(term, kind=None, reason=problems[0])
    offset = float(params.get("offset", DEFAULT_OFFSET))
    return replace(term, kind="height_scan", size=scan.count, offset=offset, scan=scan, reason="")
