"""cProfile of the full runtime (item ``profile``, not part of the default run).

Runs the tick benchmark's runtime (``bench.tick.make_runtime``, SimClock, goals, after RAMP_IN)
for ``ticks`` ticks under :mod:`cProfile` and lists the functions with the most own time
(``tottime``), in us per tick. cProfile adds its own cost to every Python call, so absolute
figures are inflated (C calls such as ``mj_step`` less so than Python-heavy stages); use it for
the ranking, and the ``tick`` item for the figures. The ``gc.collect`` that ``Runtime.run`` does
once before its loop is left out.
"""

from __future__ import annotations

import cProfile
import pstats

from bench.common import BenchPolicy


def measure(bp: BenchPolicy, ticks: int, top: int = 25) -> dict:
    """The ``profile.<robot>`` entry of results.json: ``{"ticks", "rows": [{"function",
    "calls_per_tick", "own_us_per_tick", "cumulative_us_per_tick"}]}``, most own time first."""
    from bench.tick import make_runtime, warm_up

    rt, goals = make_runtime(bp)
    warm_up(rt, goals)
    prof = cProfile.Profile()
    prof.enable()
    rt.run(ticks)
    prof.disable()
    stats = pstats.Stats(prof)
    rows = []
    for (filename, line, name), (_cc, nc, tt, ct, _callers) in stats.stats.items():
        if name == "<built-in method gc.collect>":
            continue  # once per Runtime.run, before the first tick
        where = filename.split("site-packages/")[-1].split("/main/")[-1]
        rows.append(
            {
                "function": f"{name} ({where}:{line})" if line else name,
                "calls_per_tick": nc / ticks,
                "own_us_per_tick": 1e6 * tt / ticks,
                "cumulative_us_per_tick": 1e6 * ct / ticks,
            }
        )
    rows.sort(key=lambda r: r["own_us_per_tick"], reverse=True)
    return {"ticks": ticks, "rows": rows[:top]}
