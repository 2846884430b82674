"""A soak's results by the ground its sessions walked on (:mod:`sim2real.eval.world.terrain`): one
row per terrain kind and level (a session's ``randomization.terrain``; the plane's sessions as
``plane``) with its falls (count and per hour), tracking success (share of RUNNING time within
0.2 m/s of the command, over the sessions a velocity commands: a motion clip's, counted in
``clip_sessions``, have none), distance and the runtime's interventions (share of ticks), and
what the robots did there, from the truth (:mod:`sim2real.eval.soak.terrain_figures`, a
session's ``locomotion.on_terrain``): s RUNNING on the tiles' feature (the steps, the slope, the
obstacles), on the central platform and off the tiles, m walked on the feature, crossings out
(platform to rim) and in (rim to platform), and the falls by the part they happened on.
report.json's ``totals.by_terrain`` (None when no session had terrain) and the console's lines.
"""

from __future__ import annotations

from sim2real.eval.world.tile_parts import PARTS

#: A row's figures of what the robots did, summed over its sessions (``locomotion.on_terrain``).
ON_TERRAIN = ("feature_s", "platform_s", "off_s", "feature_m", "crossings_out", "crossings_in")


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
        # velocity tracking of the sessions a velocity commands (a clip's means nothing)
        vel = [r for r in rs if r["locomotion"].get("commanded_by", "velocity") == "velocity"]
        running = sum(r["locomotion"]["running_s"] for r in vel)
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
                "clip_sessions": len(rs) - len(vel),
                "tracking_success": (
                    sum(r["locomotion"]["tracked_s"] for r in vel) / running if running else None
                ),
                "distance_m": sum(r["locomotion"]["distance_m"] for r in rs),
                "interventions_fraction": any_ / ticks if ticks else 0.0,
                "latched_faults": sum(r["runtime"]["latched_faults"] for r in rs),
                **_on_terrain(rs),
            }
        )
        walks = [(r["locomotion"].get("on_terrain") or {}).get("curriculum") for r in rs]
        if walks and all(w is not None for w in walks):
            rows[-1]["curriculum"] = sum_walks(walks)
    return rows


def sum_walks(walks: list[dict]) -> dict:
    """The curriculum walks (:meth:`sim2real.eval.soak.curriculum_walk.CurriculumWalk.summary`)
    of a row's sessions summed: counts and each level's seconds and episodes added,
    ``first_level`` and ``level`` as lists over the sessions."""
    out = {"episode_length_s": walks[0]["episode_length_s"], "rule": walks[0]["rule"]}
    for key in ("episodes_ended", "moved_up", "moved_down", "stayed"):
        out[key] = sum(w[key] for w in walks)
    out["ended_by"] = {k: sum(w["ended_by"][k] for w in walks) for k in walks[0]["ended_by"]}
    out["first_level"] = [w["first_level"] for w in walks]
    out["level"] = [w["level"] for w in walks]
    levels: dict[str, dict] = {}
    for w in walks:
        for k, v in w["levels"].items():
            at = levels.setdefault(k, {"s": 0.0, "episodes": 0})
            at["s"] += v["s"]
            at["episodes"] += v["episodes"]
    out["levels"] = dict(sorted(levels.items(), key=lambda kv: int(kv[0])))
    return out


def walk_text(walk: dict) -> str:
    """One line of a curriculum walk (a session's or :func:`sum_walks`'): its episodes, how they
    ended, the moves, the levels first and last, and the seconds walked on each level's tiles."""
    by = walk["ended_by"]
    levels = ", ".join(f"@{k} {v['s']:.0f} s" for k, v in walk["levels"].items())

    def listed(x) -> str:
        return ",".join(str(v) for v in x) if isinstance(x, list) else str(x)

    return (
        f"curriculum walk: {walk['episodes_ended']} episodes ended ({by['timeout']} timeouts of "
        f"{walk['episode_length_s']:g} s, {by['stop']} stops): up {walk['moved_up']}, down "
        f"{walk['moved_down']}, stayed {walk['stayed']}; level {listed(walk['first_level'])} -> "
        f"{listed(walk['level'])}; walking on level {levels or 'none'}"
    )


def _on_terrain(results: list[dict]) -> dict:
    """The sums of :data:`ON_TERRAIN` and the falls by part (``falls_on``) over ``results``
    (sessions of one kind and level), with the feature's noun; the plane's, or sessions
    without the figures, give None for each."""
    figures = [r["locomotion"].get("on_terrain") for r in results]
    if not figures or any(f is None for f in figures):
        return {"feature": None, **dict.fromkeys(ON_TERRAIN), "falls_on": None}
    out: dict = {"feature": figures[0]["feature"]}
    out |= {k: sum(f[k] for f in figures) for k in ON_TERRAIN}
    return out | {"falls_on": {p: sum(f["falls_on"][p] for f in figures) for p in PARTS}}


def terrain_lines(rows: list[dict] | None) -> list[str]:
    """The console's lines of :func:`terrain_rows` (none without terrain)."""
    if not rows:
        return []
    out = ["  by terrain   (kind@level: sessions, falls per hour, tracking, interventions;"]
    out.append("                then what the robots did, from the truth: s walking on the tile's")
    out.append("                feature, crossings out (platform to rim) and in, falls by place)")
    for row in rows:
        ts = row["tracking_success"]
        clips = row.get("clip_sessions", 0)
        tracking = (
            "n/a (a clip)" if ts is None and clips == row["sessions"]
            else "n/a" if ts is None else f"{100 * ts:.1f} %"
        )  # fmt: skip
        out.append(
            f"    {row['terrain']:<22} {row['sessions']:>4} sessions, {row['falls']} falls "
            f"({row['falls_per_hour']:.2f}/h), tracking {tracking}"
            f", interventions {100 * row['interventions_fraction']:.2f} % of ticks"
        )
        if row.get("falls_on") is not None:
            out.append(f"    {'':<22} {did_line(row)}")
        if row.get("curriculum") is not None:
            out.append(f"    {'':<22} {walk_text(row['curriculum'])}")
    return out


def did_line(row: dict) -> str:
    """What the robots of a row did: ``90 s on the steps (12.5 m), 10 s on the platform, 0 s
    off the tiles; 1 crossing (out 1, in 0); 0 falls on the steps (1 on the platform, 0 off)``."""
    n, at = row["crossings_out"] + row["crossings_in"], row["falls_on"]
    noun = row["feature"]
    return (
        f"{row['feature_s']:.0f} s on the {noun} ({row['feature_m']:.1f} m), "
        f"{row['platform_s']:.0f} s on the platform, {row['off_s']:.0f} s off the tiles; "
        f"{n} crossing{'' if n == 1 else 's'} (out {row['crossings_out']}, in "
        f"{row['crossings_in']}); {at['feature']} falls on the {noun} ({at['platform']} on the "
        f"platform, {at['off']} off the tiles)"
    )
