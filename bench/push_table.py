"""The push benchmark's table (:mod:`bench.push_reference`): per policy, its own loop's runs and
ours side by side (pushes survived before the fatal one, falls per hour walked, ticks past a hard
limit, interventions, upright stops, the after-push error) with the paired sign test, and per
terrain kind."""

from __future__ import annotations

from math import comb

import numpy as np

from sim2real.stacks.loops.bare import STOP_RAISED, Run


def survived(run: Run) -> int:
    """Pushes survived: those applied, less the fatal one (the last before a fall)."""
    return len(run.pushes) - (1 if run.fell_at is not None and run.pushes else 0)


def sign_test(own: list[int], ours: list[int]) -> tuple[int, int, int, float]:
    """(same, ours fewer, ours more, two-sided sign test p) over paired counts."""
    a, b = np.array(own), np.array(ours)
    n, k = int((a != b).sum()), int((b < a).sum())
    p = min(1.0, 2 * sum(comb(n, i) for i in range(min(k, n - k) + 1)) / 2**n) if n else 1.0
    return int((a == b).sum()), k, n - k, p


def summary(runs: list[Run]) -> dict:
    """Pushes survived, falls, falls per hour walked, interventions per RUNNING tick (and per
    tick of undisturbed walking, ``quiet``), ticks with a joint past a hard limit on the truth
    (``past_limit``) and pushes applied, upright stops, and the after-push error's mean (m/s,
    over the judged ticks) of ``runs``."""
    walked = sum(r.walked for r in runs)
    falls = sum(r.fell_at is not None for r in runs)
    ticks = sum(r.ticks for r in runs)
    after = [r.after_push for r in runs if r.after_push]
    n = sum(a["ticks"] for a in after)
    checks: dict = {}
    for r in runs:
        for k, v in r.checks.items():
            checks[k] = checks.get(k, 0) + v
    return {
        "survived": sum(survived(r) for r in runs),
        "falls": falls,
        "falls_per_hour": 3600.0 * falls / walked if walked else float("nan"),
        "interventions": sum(r.intervened for r in runs) / ticks if ticks else None,
        "quiet": sum(r.quiet_intervened for r in runs) / q
        if (q := sum(r.quiet_ticks for r in runs))
        else None,
        "past_limit": sum(r.past_limit for r in runs),
        "pushes": sum(len(r.pushes) for r in runs),
        "checks": checks,
        "upright_stops": sum(r.upright_stop for r in runs),
        "after_push": sum(a["mean_m_s"] * a["ticks"] for a in after) / n if n else None,
        "after_push_worst": max((a["worst_push_mean_m_s"] for a in after), default=None),
        "causes": sorted({r.cause for r in runs if r.cause}),
        "raised": sum(r.cause == STOP_RAISED for r in runs),
    }


def table(results: dict[str, tuple], args) -> list[str]:
    """The side-by-side table's lines (markdown); ``results``: per policy (entry, own loop's
    runs, ours, and the more own loops' runs by row name, :func:`run_seed`). A more row's
    paired column pairs it with the row before it (fed our estimate: with fed the truth)."""
    lines = [
        "| policy | loop | pushes survived | falls | falls per hour | ticks past a hard limit "
        "(per push) | interventions per tick (undisturbed walking) | upright stops | after-push "
        "error mean / worst push (m/s) | paired: same / ours earlier / later (p) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, (entry, own, ours, more_rows) in results.items():
        a, b = summary(own), summary(ours)
        same, fewer, more, p = sign_test([survived(r) for r in own], [survived(r) for r in ours])
        share = f" ({b['survived'] / a['survived']:.1%} of its own)" if a["survived"] else ""
        after = (
            "-"
            if b["after_push"] is None or b["after_push_worst"] is None
            else f"{b['after_push']:.3f} / {b['after_push_worst']:.3f}"
        )
        checks = ", ".join(f"{k} {v}" for k, v in sorted(b["checks"].items()))
        quiet = "-" if b["quiet"] is None else f"{b['quiet']:.2%}"
        lines.append(
            f"| {name} | own ({entry.own_loop}) | {a['survived']} | {a['falls']}/{len(own)} | "
            f"{a['falls_per_hour']:.0f} | {_past(a)} | - | - | - | |"
        )
        previous = None
        for row, runs in more_rows.items():
            c = summary(runs)
            paired = ""
            if previous is not None:
                x, y, z, q = sign_test([survived(r) for r in previous],
                                       [survived(r) for r in runs])  # fmt: skip
                paired = f"with the row above: {x} / {y} / {z} (p = {q:.3f})"
            lines.append(
                f"| {name} | {row} | {c['survived']} | {c['falls']}/{len(runs)} | "
                f"{c['falls_per_hour']:.0f} | {_past(c)} | - | - | - | {paired} |"
            )
            previous = runs
        lines.append(
            f"| {name} | our runtime | {b['survived']}{share} | {b['falls']}/{len(ours)}"
            f"{f' ({raised} raised)' if (raised := b['raised']) else ''} | "
            f"{b['falls_per_hour']:.0f} | {_past(b)} | {b['interventions']:.4%}"
            f"{f' ({checks})' if checks else ''} ({quiet}) | {b['upright_stops']} | {after} | "
            f"{same} / {fewer} / {more} (p = {p:.3f}) |"
        )
    return lines


def _past(s: dict) -> str:
    """A summary's ticks past a hard limit, and per push applied."""
    per = f" ({s['past_limit'] / s['pushes']:.1f})" if s["pushes"] else ""
    return f"{s['past_limit']}{per}"


def terrain_table(results: dict, kinds: list[str]) -> list[str]:
    """Pushes survived per terrain kind (``kinds``: each seed's ``--terrain`` draw's, in the
    runs' order), own loop / ours, per policy."""
    lines = ["| policy | terrain | runs | pushes survived own / ours | falls own / ours |"]
    lines.append("| --- | --- | --- | --- | --- |")
    for name, (_, own, ours, _) in results.items():
        for kind in sorted(set(kinds)):
            at = [i for i, k in enumerate(kinds) if k == kind]
            a = sum(survived(own[i]) for i in at)
            b = sum(survived(ours[i]) for i in at)
            fa = sum(own[i].fell_at is not None for i in at)
            fb = sum(ours[i].fell_at is not None for i in at)
            lines.append(f"| {name} | {kind} | {len(at)} | {a} / {b} | {fa} / {fb} |")
    return lines
