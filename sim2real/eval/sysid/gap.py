"""The reality gap of a log: how far the robot's readings were from the plant replaying its
commands, with the described motors and with a plant motors file (the fitted ones), per joint
(RMS and largest error, rad), written as ``gap.json``, ``gap.md``, ``gap.png`` and ``gap.html``
(the table and the plot in one page).
"""

from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path

import numpy as np

from sim2real.eval.sysid.replay import reading_errors, replay
from sim2real.robots.files import atomic_write


def gap_report(robot, meta: dict, arrays: dict, plants: dict) -> dict:
    """Per joint, for each plant of ``plants`` (name -> :class:`sim2real.robots.plant_motors.PlantMotors`
    or None for the described motors): the readings' RMS and largest error (rad) off the
    replay, and the errors themselves (``(ticks, n)`` rad, under ``"_errors"``, for the plot).

    Raises:
        ValueError: the log is of other joints or another control period.
    """
    report = {"robot": robot.name, "ticks": len(arrays["t"]), "plants": {}}
    errors = {}
    for name, plant in plants.items():
        e = reading_errors(arrays, replay(robot, meta, arrays, plant), robot.control_period)
        errors[name] = e
        report["plants"][name] = {
            "rms_rad": dict(
                zip(robot.joint_names, np.sqrt(np.nanmean(e**2, axis=0)).tolist(), strict=True)
            ),
            "max_rad": dict(
                zip(robot.joint_names, np.nanmax(np.abs(e), axis=0).tolist(), strict=True)
            ),
        }
    report["_errors"] = errors
    return report


def write_gap(report: dict, out: Path, t: np.ndarray) -> list[Path]:
    """Write ``gap.json``, ``gap.md`` and (with matplotlib) ``gap.png`` of ``report``
    (:func:`gap_report`) into the folder ``out``; the paths written."""
    out.mkdir(parents=True, exist_ok=True)
    errors = report.pop("_errors")
    written = [atomic_write(out / "gap.json", json.dumps(report, indent=2))]
    names = list(report["plants"])
    joints = list(report["plants"][names[0]]["rms_rad"])
    lines = [
        f"# Reality gap: {report['robot']}, {report['ticks']} ticks",
        "",
        "Readings minus the plant replaying the log's commands, per joint, mrad (RMS / max).",
        "",
        "| joint | " + " | ".join(names) + " |",
        "| --- |" + " --- |" * len(names),
    ]
    for j in joints:
        cells = [
            f"{1e3 * report['plants'][n]['rms_rad'][j]:.2f} / "
            f"{1e3 * report['plants'][n]['max_rad'][j]:.1f}"
            for n in names
        ]
        lines.append(f"| {j} | " + " | ".join(cells) + " |")
    written.append(atomic_write(out / "gap.md", "\n".join(lines) + "\n"))
    png = _plot(errors, names, joints, t)
    if png is not None:
        written.append(atomic_write(out / "gap.png", png))
    written.append(atomic_write(out / "gap.html", _html(report, names, joints, png)))
    return written


def _html(report: dict, names: list[str], joints: list[str], png: bytes | None) -> str:
    """The gap's table (mrad, RMS / max) and its plot (inline) as one HTML page."""
    head = "".join(f"<th>{html.escape(n)}</th>" for n in names)
    rows = "".join(
        f"<tr><td>{html.escape(j)}</td>"
        + "".join(
            f"<td>{1e3 * report['plants'][n]['rms_rad'][j]:.2f} / "
            f"{1e3 * report['plants'][n]['max_rad'][j]:.1f}</td>"
            for n in names
        )
        + "</tr>"
        for j in joints
    )
    img = "" if png is None else (
        f'<img alt="errors" src="data:image/png;base64,{base64.b64encode(png).decode()}">'
    )  # fmt: skip
    title = f"Reality gap: {html.escape(report['robot'])}, {report['ticks']} ticks"
    return (
        f"<!doctype html><html><head><meta charset='utf-8'><title>{title}</title></head><body>"
        f"<h1>{title}</h1><p>Readings minus the plant replaying the log's commands, mrad "
        f"(RMS / max).</p><table border='1'><tr><th>joint</th>{head}</tr>{rows}</table>"
        f"{img}</body></html>\n"
    )


def _plot(errors: dict, names: list[str], joints: list[str], t: np.ndarray) -> bytes | None:
    """The errors per joint over time as PNG bytes (None without matplotlib)."""
    try:
        import matplotlib.pyplot as plt
    except ImportError:  # the report extra
        return None
    fig, axes = plt.subplots(len(joints), 1, figsize=(8, 1.6 * len(joints)), sharex=True)
    for j, ax in enumerate(np.atleast_1d(axes)):
        for n in names:
            ax.plot(t, 1e3 * errors[n][:, j], lw=0.7, label=n)
        ax.set_ylabel(f"{joints[j]}\nmrad", fontsize=7)
    np.atleast_1d(axes)[0].legend(fontsize=7, loc="upper right")
    np.atleast_1d(axes)[-1].set_xlabel("t (s)")
    fig.tight_layout()
    png = io.BytesIO()
    fig.savefig(png, format="png", dpi=90)
    plt.close(fig)
    return png.getvalue()
