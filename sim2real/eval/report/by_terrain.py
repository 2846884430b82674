"""A soak's results by the ground its sessions walked on (:mod:`sim2real.eval.world.terrain`): one row per
terrain kind and level (a session's ``randomization.terrain``; the plane's sessions as ``plane``)
with its falls (count and per hour), tracking success (share of RUNNING time within 0.2 m/s of the
command), distance and the runtime's interventions (share of ticks). report.json's
``totals.by_terrain`` (None when no session had terrain) and the console's lines.
"""

from __future__ import annotations


def _key(result: dict) -> tuple[str, str, int | None]:
    t = result["randomization"].get("terrain")
    if t is None:
        return ("plane", "plane", None)
    return (t.get("label", t["kind"]), t["kind"], t.get("level"))


def terrain_rows(results: list[dict]) -> list[dict] | None:
    """One row per terrain (module docstring) over the legged sessions of ``results``, ordered
    by kind then level; None when none of them had terrain."""
    legged = [r for r in results if r.get("locomotion") is not None]
    if not any(r["randomization"].get("terrain") for r in legged):
        return None
    groups: dict[tuple, list[dict]] = {}
    for r in legged:
        groups.setdefault(_key(r), []).append(r)
    rows = []
    for (label, kind, level), rs in sorted(
        groups.items(), key=lambda kv: (kv[0][1], kv[0][2] or 0)
    ):
        hours = sum(r["simulated_hours"] for r in rs)
        falls = sum(r["locomotion"]["falls"] for r in rs)
        running = sum(r["locomotion"]["running_s"] for r in rs)
        ticks = sum(r["interventions"]["ticks"] for r in rs)
        any_ = sum(r["interventions"]["any"]["count"] for r in rs)
        rows.append(
            {
                "terrain": label,
                "kind": kind,
                "level": level,
                "sessions": len(rs),
                "simulated_hours": hours,
                "falls": falls,
                "falls_per_hour": falls / hours if hours > 0 else 0.0,
                "tracking_success": (
                    sum(r["locomotion"]["tracked_s"] for r in rs) / running if running else None
                ),
                "distance_m": sum(r["locomotion"]["distance_m"] for r in rs),
                "interventions_fraction": any_ / ticks if ticks else 0.0,
                "latched_faults": sum(r["runtime"]["latched_faults"] for r in rs),
            }
        )
    return rows


def terrain_lines(rows: list[dict] | None) -> list[str]:
    """The console's lines of :func:`terrain_rows` (none without terrain)."""
    if not rows:
        return []
    out = ["  by terrain   (kind@level: sessions, falls per hour, tracking, interventions)"]
    for row in rows:
        ts = row["tracking_success"]
        out.append(
            f"    {row['terrain']:<22} {row['sessions']:>4} sessions, {row['falls']} falls "
            f"({row['falls_per_hour']:.2f}/h), tracking {'n/a' if ts is None else f'{100 * ts:.1f} %'}"
            f", interventions {100 * row['interventions_fraction']:.2f} % of ticks"
        )
    return out
