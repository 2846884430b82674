"""The files of a sim-to-sim comparison (:func:`sim2real.eval.sim2sim.compare.compare`): ``sim2sim.json``
(the comparison itself), ``sim2sim.md`` (tables: figure | one column per engine | gap | flag, in
total and per session, then the verdict) and ``sim2sim.png`` (a bar chart of the totals, one panel
per figure, the engines side by side; matplotlib's Agg backend, the ``report`` extra).

Every file is written atomically (:func:`sim2real.robots.files.atomic_write`: a temporary file in the same
folder, then ``os.replace``), so a crash leaves the previous file or the new one, never a part.
"""

from __future__ import annotations

import json
import math
import os
import textwrap
from pathlib import Path

from sim2real.robots.files import atomic_path, atomic_write

#: Decimals of a value in the markdown table, by unit (counts: as integers).
DECIMALS = {"%": 1, "% of ticks": 3, "degC": 1, "m/s": 3}
#: Panels per row of the bar chart.
CHART_COLUMNS = 4


def _number(value: float | None, unit: str) -> str:
    if value is None:
        return "n/a"
    decimals = DECIMALS.get(unit)
    if decimals is None:
        return f"{value:g}"
    return f"{value:.{decimals}f}"


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _table(figures: list[dict], engines: list[str]) -> list[str]:
    lines = [
        "| figure | " + " | ".join(engines) + " | gap | flag |",
        "|---|" + "---|" * len(engines) + "---|---|",
    ]
    for f in figures:
        unit = f["unit"]
        notes = f.get("notes") or {}
        values = []
        for e in engines:
            text = _number(f["values"].get(e), unit)
            if notes.get(e):
                text += f" ({notes[e]})"
            values.append(text)
        if f["gap"] is None:
            gap = "n/a"
        else:
            gap = f"{_number(f['gap'], unit)} ({100 * f['relative_gap']:.1f} %)"
        flag = f"**engine-dependent**: {f['reason']}" if f["engine_dependent"] else "-"
        label = f"{f['label']} ({unit})"
        lines.append("| " + " | ".join(_cell(c) for c in [label, *values, gap, flag]) + " |")
    return lines


def totals_table(result: dict) -> str:
    """The markdown table of the totals: figure | one column per engine | gap | flag."""
    return "\n".join(_table(result["totals"], result["engines"]))


def markdown(result: dict) -> str:
    """sim2sim.md's text: the reports compared, the totals' table, each session's table, the
    verdict, the warnings and the thresholds."""
    engines = result["engines"]
    lines = [
        f"# Sim-to-sim: {result['robot']}, {result['policy']}",
        "",
        f"{len(result['seeds'])} sessions (seeds {', '.join(map(str, result['seeds']))}) of "
        f"{result['hours']:g} simulated h on each engine.",
        "",
    ]
    for e in engines:
        info = result["reports"][e]
        soak = "passed" if info["passed"] else "failed: " + ", ".join(info["failed_checks"])
        lines.append(f"- {e}: `{info['path']}` (soak {soak}, exit code {info['exit_code']})")
    lines += ["", f"**Verdict: {result['verdict']}**", "", "## Totals", ""]
    lines += _table(result["totals"], engines)
    for row in result["sessions"]:
        ids = ", ".join(f"{e} {i}" for e, i in row["ids"].items())
        lines += ["", f"## Seed {row['seed']} ({ids})", ""]
        lines += _table(row["figures"], engines)
    if result["flagged"]:
        lines += ["", "## Engine-dependent", ""]
        lines += [f"- {f['label']} ({f['where']}): {f['reason']}" for f in result["flagged"]]
    if result["warnings"]:
        lines += ["", "## Warnings", ""]
        lines += [f"- {w}" for w in result["warnings"]]
    lines += ["", "## Thresholds", ""]
    lines += [f"- `{k}` = {v:g}" for k, v in result["thresholds"].items()]
    lines += ["", "Fields read (per session `sessions[i].FIELD`, in total `totals.FIELD`):", ""]
    lines += [f"- {k}: `{v}`" for k, v in result["fields"].items()]
    return "\n".join(lines) + "\n"


def plot(result: dict, path: str | os.PathLike) -> Path:
    """Write the bar chart of the totals to ``path`` (PNG, atomically): one panel per figure in
    its own unit, one bar per engine; an engine-dependent figure's title is red.

    Raises:
        ImportError: matplotlib is not installed (``pip install '.[report]'``).
        OSError: the folder does not exist or is not writable.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figures, engines = result["totals"], result["engines"]
    cols = min(CHART_COLUMNS, len(figures))
    rows = math.ceil(len(figures) / cols)
    fig = Figure(figsize=(3.2 * cols, 2.7 * rows + 0.6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    colors = [f"C{i}" for i in range(len(engines))]
    for ax, f in zip(axes, figures, strict=False):
        heights = [f["values"].get(e) for e in engines]
        bars = ax.bar(
            range(len(engines)),
            [0.0 if h is None else h for h in heights],
            color=colors,
        )
        ax.bar_label(bars, [_number(h, f["unit"]) for h in heights], fontsize=7)
        defined = [h for h in heights if h is not None]
        if not defined or min(defined) >= 0:
            top = max(defined, default=0.0)
            ax.set_ylim(0.0, 1.15 * top if top > 0 else 1.0)
        ax.set_xticks(range(len(engines)), engines, fontsize=8)
        ax.set_ylabel(f["unit"], fontsize=8)
        ax.tick_params(axis="y", labelsize=7)
        dependent = f["engine_dependent"]
        title = f["label"] + ("\nENGINE-DEPENDENT" if dependent else "")
        ax.set_title(title, fontsize=9, color="red" if dependent else "black")
    for ax in axes[len(figures) :]:
        ax.set_axis_off()
    title = textwrap.fill(f"sim2sim {result['robot']}: {result['verdict']}", 45 * cols)
    fig.suptitle(title, fontsize=10)
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=90)
    return path


def write_sim2sim(out: str | os.PathLike, result: dict) -> dict[str, Path]:
    """Write ``out/sim2sim.json``, ``out/sim2sim.md`` and ``out/sim2sim.png`` (the folder is
    created), each atomically; without matplotlib the chart is left out.

    Returns:
        ``{"json": path, "md": path, "png": path}`` (no ``png`` without matplotlib).

    Raises:
        OSError: ``out`` cannot be created or written.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {
        "json": atomic_write(out / "sim2sim.json", json.dumps(result, indent=1, allow_nan=False)),
        "md": atomic_write(out / "sim2sim.md", markdown(result)),
    }
    try:
        paths["png"] = plot(result, out / "sim2sim.png")
    except ImportError:
        pass
    return paths
