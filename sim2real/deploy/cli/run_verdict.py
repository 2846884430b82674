"""``deploy-run``'s exit code from its report (the codes: :mod:`sim2real.deploy.cli.deploy_run`'s
docstring): a divergence, then a hard violation (true-state ticks past what the policy's own loop
allows: :mod:`sim2real.deploy.cli.own_loop_check`), a latched fault or a true fall, a dance that
left its spot.
"""

from __future__ import annotations

EXIT_CLEAN, EXIT_HARD_VIOLATION, EXIT_FAULT, EXIT_BAD_INPUT, EXIT_DIVERGED = 0, 1, 2, 3, 4
EXIT_LEFT_SPOT = 5


def exit_code(report: dict, rig) -> int:
    """The exit code of a run's ``report`` (module docstring); sets ``report["hard_violations"]``
    (true-state ticks by type, lying down included, that fail the run) and
    ``report["within_own_loop"]`` (those its own loop allows: ``report["own_loop"]``)."""
    from sim2real.deploy.monitors.violations import HARD_VIOLATION_TYPES

    v = report["violations"]
    true = {"hard_limit": 0} if v is None else {**v["by_type"], "any": v["any"]}
    down = {} if v is None else v["while_down"]
    hard = {
        k: int(true.get(k, 0)) + int(down.get(k, 0))
        for k in HARD_VIOLATION_TYPES
        if true.get(k, 0) + down.get(k, 0)
    }
    judged = report.get("own_loop") or {}
    allowed = {
        k for k, f in (judged.get("verdict") or {}).items() if f["passed"] and not down.get(k)
    }
    report["within_own_loop"] = {k: n for k, n in hard.items() if k in allowed}
    hard = {k: n for k, n in hard.items() if k not in allowed}
    report["hard_violations"] = hard
    if report["diverged"]:
        return EXIT_DIVERGED
    if hard or report["faults"]["by_cause"]["hard_limit"] > 0:
        return EXIT_HARD_VIOLATION
    # an operator's own stop (damp, lie down) is where an operated run may end: not a fault
    operated = report.get("operator") is not None
    stopped = [
        m in ("FAULTED", "SAFE_STOP") and not (operated and c == "operator")
        for m, c in zip(report["final_state"], report["final_cause"], strict=True)
    ]
    if any(stopped) or rig.true_falls():
        return EXIT_FAULT
    if ((report.get("tracking") or {}).get("travel") or {}).get("off_path"):
        return EXIT_LEFT_SPOT  # a dance that left its spot: a finding, never a success
    return EXIT_CLEAN
