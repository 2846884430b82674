"""The report of ``policy-export --inspect``: its entries and its text.

:func:`tensor_entry` is an input, output or state entry (``{"name", "shape", "dtype"}``; shapes
are lists, ``"batch"`` a torch source's dynamic batch axis), :func:`spec_summary` an embedded
PolicySpec (its JSON, whether :class:`~sim2real.deploy.spec.policy_spec.PolicySpec` accepts it, a
summary), and :func:`format_report` an :func:`~sim2real.deploy.export.inspect_policy.inspect_file` result as
text for a terminal.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

#: The metadata key ``policy-export --domain`` stores a training domain under (the ranges file's
#: text; ``sim2real.eval.world.domain.METADATA_KEY``), printed whole.
DOMAIN_KEY = "training_domain"


def tensor_entry(name: str, shape, dtype: str) -> dict[str, Any]:
    return {"name": name, "shape": list(shape), "dtype": dtype}


def spec_summary(text: str, where: str) -> dict[str, Any]:
    """The embedded PolicySpec: its JSON, whether :class:`PolicySpec` accepts it, a summary."""
    from sim2real.deploy.spec.policy_spec import PolicySpec

    try:
        raw = json.loads(text)
    except json.JSONDecodeError as exc:
        return {"valid": False, "error": f"{where}: not JSON: {exc}"}
    out: dict[str, Any] = {"json": raw, "valid": True}
    try:
        PolicySpec.from_json(text, source=where)
    except Exception as exc:  # noqa: BLE001 - SpecError and friends: reported, not raised
        out.update(valid=False, error=str(exc))
    if isinstance(raw, Mapping):
        blocks = raw.get("observation") or raw.get("observation_blocks") or []
        action = raw.get("action") if isinstance(raw.get("action"), Mapping) else {}
        out["summary"] = {
            "robot": raw.get("robot"),
            "control_rate": raw.get("control_rate"),
            "observation": [
                f"{b.get('name')}[{b.get('size')}]" for b in blocks if isinstance(b, Mapping)
            ],
            "action": f"{action.get('mode')} [{action.get('size')}], clip {action.get('clip')}",
            "history": history_text(raw.get("history"), blocks),
        }
        images = raw.get("images") or []
        if images:  # a camera policy's image inputs (sim2real.deploy.spec.camera)
            out["summary"]["images"] = [image_text(b) for b in images]
    return out


def image_text(block) -> str:
    """One line of a spec's image block (its JSON: a :class:`~sim2real.deploy.spec.camera.
    DepthImageBlock` or, ``"kind": "rgb"``, an :class:`~sim2real.deploy.spec.camera.
    RgbImageBlock`): input, camera, frame, crop, resize, clip or colour layout, normalisation,
    history, rate."""
    from sim2real.deploy.spec.camera import DepthImageBlock, RgbImageBlock

    if not isinstance(block, Mapping):
        return f"{block!r} (not a table)"
    if block.get("kind") == "rgb":
        b = {**RgbImageBlock().to_dict(), **block}
        try:
            norm = "x/255" + (
                f", mean {list(b['mean'])} std {list(b['std'])}"
                if b["normalisation"] == "mean_std"
                else ""
            )
            return (
                f"{b['input']} <- colour camera '{b['camera']}' {b['shape'][0]}x{b['shape'][1]} "
                f"at {b['rate']:g} Hz, crop {list(b['crop'])} (top, bottom, left, right), resize "
                f"{b['resize'][0]}x{b['resize'][1]} {b['interpolation']}, {b['channel_order']} "
                f"{b['layout']} {norm}, {b['frames']} frames {b['skip']} apart, latency "
                f"{b['latency']:g} s"
            )
        except (TypeError, ValueError, IndexError, KeyError):
            return json.dumps(block)
    b = {**DepthImageBlock().to_dict(), **block}
    try:
        return (
            f"{b['input']} <- depth camera '{b['camera']}' {b['shape'][0]}x{b['shape'][1]} at "
            f"{b['rate']:g} Hz, crop {list(b['crop'])} (top, bottom, left, right), resize "
            f"{b['resize'][0]}x{b['resize'][1]} {b['interpolation']}, clip {b['near']:g}-"
            f"{b['far']:g} m {b['normalisation']}, {b['frames']} frames {b['skip']} apart, "
            f"latency {b['latency']:g} s"
        )
    except (TypeError, ValueError, IndexError, KeyError):
        return json.dumps(block)


def history_text(history, blocks) -> str:
    """The summary line of a spec's frame history (its JSON ``history``, an
    :class:`~sim2real.deploy.spec.history.ObservationHistory`: length, order, layout, fill,
    the ticks per block) and the entries it stacks: "none" without one (the graph reads one
    frame a tick)."""
    from sim2real.deploy.spec.history import ObservationHistory, stacked_dim

    sizes = tuple(b.get("size") for b in blocks if isinstance(b, Mapping))
    frame = sum(sizes) if all(isinstance(s, int) for s in sizes) else None
    if history is None:
        return "none (one frame a tick" + (f": {frame} entries)" if frame is not None else ")")
    if not isinstance(history, Mapping):
        return f"{history!r} (not a table)"
    default = ObservationHistory(length=1)
    h = {k: history.get(k, getattr(default, k)) for k in ("length", "order", "layout", "fill")}
    lengths = history.get("lengths") or ()
    text = f"{h['length']} ticks, {h['order']}, {h['layout']}, fill {h['fill']}"
    if lengths:
        text += f", ticks per block {list(lengths)}"
    try:
        stacked = stacked_dim(ObservationHistory(**h, lengths=tuple(lengths)), sizes)
    except (TypeError, ValueError):
        return text
    return text + f" (frame {frame} entries, input {stacked})"


def _shape(shape: list) -> str:
    return "[" + ", ".join(str(d) for d in shape) + "]"


def format_report(info: Mapping[str, Any]) -> str:
    """:func:`inspect_file`'s result as text for a terminal."""
    lines = [f"{info['file']}: {info['format']}"]
    for key in ("inputs", "outputs"):
        if info.get(key):
            lines.append(f"  {key}:")
            lines += [
                f"    {t['name']:<12} {t['dtype']:<8} {_shape(t['shape'])}" for t in info[key]
            ]
    if info.get("state"):
        lines.append("  recurrent state:")
        for s in info["state"]:
            extra = ""
            if "output_shape" in s:
                extra += f"  (output shape {_shape(s['output_shape'])} differs!)"
            if s.get("declared_initial_state"):
                extra += "  (declared initial state)"
            if "lifted_from" in s:
                extra += f"  (from {s['lifted_from']})"
            lines.append(
                f"    {s['input']} -> {s['output']}  {s['dtype']} {_shape(s['shape'])}{extra}"
            )
    else:
        lines.append("  recurrent state: none")
    whole = ("policy_spec", DOMAIN_KEY)
    meta = {k: v for k, v in (info.get("metadata") or {}).items() if k not in whole}
    if meta:
        lines.append("  metadata:")
        for k, v in meta.items():
            text = v if isinstance(v, str) else json.dumps(v, default=str)
            lines.append(f"    {k}: {text if len(text) <= 160 else text[:157] + '...'}")
    domain = (info.get("metadata") or {}).get(DOMAIN_KEY)
    if isinstance(domain, str):
        lines.append(
            f"  training domain (metadata {DOMAIN_KEY}; soak-test runs it; each value's '# from:' "
            "line says where it came from, '# not modelled:' what the soak leaves out):"
        )
        lines += [f"    {line}" for line in domain.splitlines() if line.strip()]
    for k, v in (info.get("details") or {}).items():
        text = v if isinstance(v, str) else json.dumps(v, default=str)
        lines.append(f"  {k}: {text}")
    spec = info.get("spec")
    if spec:
        state = "valid" if spec.get("valid") else f"INVALID: {spec.get('error')}"
        lines.append(f"  policy spec ({state}):")
        for k, v in (spec.get("summary") or {}).items():
            lines.append(f"    {k}: {', '.join(v) if isinstance(v, list) else v}")
        if spec.get("json") is not None:
            lines.append("    json: " + json.dumps(spec["json"], sort_keys=True))
    elif info.get("lerobot"):
        lines += [f"  {line}" for line in info["lerobot"]]
        lines.append("  run it beside the servo loop: deploy-run --robot so101 --policy FILE")
    elif info.get("foreign"):
        from sim2real.deploy.spec.foreign.report import format_lines

        lines += format_lines(info["foreign"])
    else:
        lines.append("  policy spec: none (give one with --spec FILE.json)")
    return "\n".join(lines)
