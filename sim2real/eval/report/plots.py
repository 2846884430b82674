"""The plots of a soak report.html: matplotlib figures as base64 PNGs.

Each ``plot_*`` function takes a report (:func:`sim2real.eval.report.build.build_report`) and returns the
PNG's base64 text, which :mod:`sim2real.eval.report.html` embeds (``data:image/png;base64,...``). matplotlib
(the
``report`` extra) is imported when a plot is drawn.
"""

from __future__ import annotations

import base64
import io

import numpy as np


def _png(fig) -> str:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _figure(rows: int = 1, cols: int = 1, height: float = 3.2):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, height * rows))
    axes = fig.subplots(rows, cols, squeeze=False)
    return fig, axes


def plot_temperatures(report: dict) -> str:
    """Winding temperature vs time per joint (one panel per session), base64 PNG."""
    sessions = report["sessions"]
    fig, axes = _figure(len(sessions), 1, 2.6)
    for ax, s in zip(axes[:, 0], sessions, strict=True):
        th = s["thermal"]
        t = np.asarray(th["curve"]["t_s"]) / 3600.0
        for joint in th["joints"]:
            ax.plot(t, th["curve"]["winding_c"][joint], label=joint)
        lo = min(th["derating_start_c"].values())
        hi = max(th["max_winding_c"].values())
        ax.axhspan(lo, hi, color="orange", alpha=0.15, label="derating band")
        ax.axhline(hi, color="red", lw=0.8, ls="--")
        ax.set_title(f"{s['id']}: winding temperature (max per interval)", fontsize=9)
        ax.set_ylabel("degC")
        ax.legend(fontsize=7, ncol=4, loc="upper left")
    axes[-1, 0].set_xlabel("simulated time (h)")
    return _png(fig)


def _stacked_hours(ax, rows: list[dict], scale, empty: str) -> None:
    """Stacked bars of ``rows[i]["counts"]`` per hour, each divided by ``scale(row)``."""
    if not rows:
        ax.text(0.5, 0.5, empty, ha="center", transform=ax.transAxes)
        return
    names = list(rows[0]["counts"])
    hours = np.array([r["hour"] for r in rows])
    bottom = np.zeros(len(rows))
    for name in names:
        values = np.array([r["counts"][name] / scale(r) for r in rows], dtype=float)
        if values.any():
            ax.bar(hours, values, bottom=bottom, label=name)
            bottom += values
    if not bottom.any():
        ax.text(0.5, 0.5, empty, ha="center", transform=ax.transAxes)
    else:
        ax.legend(fontsize=7)


def plot_violations(report: dict) -> str:
    """True-state violations per hour by type, summed over sessions (stacked bars), base64 PNG."""
    rows = report["totals"]["violations"]["per_hour"]
    fig, axes = _figure(1, 1, 3.0)
    ax = axes[0, 0]
    _stacked_hours(ax, rows, lambda r: 1.0, "no violations")
    ax.set_xlabel("hour of the session")
    ax.set_ylabel("ticks (all sessions)")
    ax.set_title("Violations (true state) per hour by type", fontsize=9)
    return _png(fig)


def plot_interventions(report: dict) -> str:
    """Interventions per hour as % of ticks by check, all sessions (stacked bars; a tick with
    several checks counts in each), with the threshold on any intervention, base64 PNG."""
    rows = report["totals"]["interventions"]["per_hour"]
    fig, axes = _figure(1, 1, 3.0)
    ax = axes[0, 0]
    _stacked_hours(ax, rows, lambda r: max(r["ticks"], 1) / 100.0, "no interventions")
    limit = report["thresholds"].get("max_intervention_rate")
    if limit is not None:
        ax.axhline(100 * limit, color="red", lw=0.8, ls="--", label="threshold (any)")
        ax.legend(fontsize=7)
    ax.set_xlabel("hour of the session")
    ax.set_ylabel("% of ticks")
    ax.set_title("Interventions (guard and smoother changed a command) per hour", fontsize=9)
    return _png(fig)


def plot_success(report: dict) -> str:
    """Goal success rate per curve interval over time, per session, base64 PNG."""
    fig, axes = _figure(1, 1, 3.0)
    ax = axes[0, 0]
    for s in report["sessions"]:
        c = s["curves"]
        t = np.asarray(c["t_s"]) / 3600.0
        # a legged session: tracked / RUNNING seconds per interval
        issued = np.diff(np.asarray(c.get("goals_issued", c.get("running_s")), dtype=float))
        reached = np.diff(np.asarray(c.get("goals_reached", c.get("tracked_s")), dtype=float))
        with np.errstate(invalid="ignore", divide="ignore"):
            rate = np.where(issued > 0, reached / np.where(issued > 0, issued, 1), np.nan)
        if len(t) > 1:
            ax.plot(t[1:], rate, marker=".", label=s["id"])
    ax.set_ylim(-0.05, 1.05)
    ax.set_xlabel("simulated time (h)")
    ax.set_ylabel("success rate")
    ax.set_title(
        "Goals reached / goals issued per interval (legged: time tracking the command)",
        fontsize=9,
    )
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, ncol=4)
    return _png(fig)


def plot_windows(report: dict) -> str:
    """Goal success rate per window (by the goals' issue time), per session, with the
    threshold, base64 PNG."""
    fig, axes = _figure(1, 1, 3.0)
    ax = axes[0, 0]
    for i, s in enumerate(report["sessions"]):
        windows = (s.get("goals") or s.get("locomotion") or {}).get("windows", [])
        if windows:  # one segment per window: windows without a goal leave gaps
            ax.hlines(
                [w["success_rate"] for w in windows],
                [w["start_s"] / 3600.0 for w in windows],
                [w["end_s"] / 3600.0 for w in windows],
                colors=f"C{i % 10}",
                label=s["id"],
            )
    limit = report["thresholds"].get("min_window_success_rate")
    if limit is not None:
        ax.axhline(limit, color="red", lw=0.8, ls="--", label="threshold")
    ax.set_ylim(-0.05, 1.05)
    ax.set_xlabel("simulated time (h)")
    ax.set_ylabel("success rate")
    ax.set_title("Goal success rate per window (windows without a goal left out)", fontsize=9)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, ncol=4)
    return _png(fig)


def plot_tick_cost(report: dict) -> str:
    """Histogram of the runtime's tick cost (without physics), all batches, base64 PNG."""
    fig, axes = _figure(1, 1, 3.0)
    ax = axes[0, 0]
    seen = set()
    for s in report["sessions"]:
        key = tuple(s["wall"]["batch"])
        if key in seen:  # every session of a batch shares the batch's histogram
            continue
        seen.add(key)
        h = s["wall"]["tick_cost_histogram"]
        if h["bin_us"]:
            edges = np.geomspace(10.0, 25_000.0, 80)  # the last bin holds the >= 20 ms overflow
            values = np.clip(np.asarray(h["bin_us"], dtype=float) + 0.5, edges[0], edges[-1])
            ax.hist(
                values, bins=edges, weights=h["count"], histtype="step", label=f"batch {list(key)}"
            )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("tick cost (us; sessions of a batch share one)")
    ax.set_ylabel("ticks")
    ax.set_title("Runtime tick cost (wall clock, without physics)", fontsize=9)
    if seen:
        ax.legend(fontsize=7)
    return _png(fig)


def plot_robustness(report: dict) -> str | None:
    """The robustness sweep (:mod:`sim2real.eval.soak.sweep`): success (tracking or goals) per level of
    each quantity, a red cross where the level's session fell, the reference's success as a
    line; None without a sweep."""
    sweep = report.get("robustness")
    if sweep is None:
        return None
    rows = [r for r in sweep["quantities"] if r["levels"]]
    if not rows:
        return None
    cols = 3
    fig, axes = _figure((len(rows) + cols - 1) // cols, cols, 2.4)
    ref = sweep["reference"]["success"]
    for ax in axes.flat[len(rows) :]:
        ax.set_visible(False)
    for ax, row in zip(axes.flat, rows, strict=False):
        levels = [lv["level"] for lv in row["levels"]]
        success = [np.nan if lv["success"] is None else lv["success"] for lv in row["levels"]]
        ax.plot(levels, success, "o-", color="tab:blue")
        pairs = zip(row["levels"], success, strict=True)
        fell = [(lv["level"], s) for lv, s in pairs if lv["falls"]]
        if fell:
            ax.plot(*zip(*fell, strict=True), "x", color="tab:red", markersize=10, label="fell")
        if ref is not None:
            ax.axhline(ref, color="gray", lw=0.8)
            ax.axhline(ref - sweep["tolerance"], color="gray", lw=0.8, ls="--")
        ax.set_title(f"{row['label']} ({row['unit']})", fontsize=9)
        ax.set_ylim(0, 1.05)
        if row["unit"] == "mu":
            ax.invert_xaxis()
    return _png(fig)
