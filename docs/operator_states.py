"""Draws docs/operator_states.png: the operator's state machine (sim2real/deploy/operator/machine.py)."""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

pos = {
    "PASSIVE": (0.0, 0.0),
    "STAND": (3.8, 0.0),
    "POLICY": (7.6, 0.0),
    "LIE": (5.7, -2.5),
    "DAMP": (1.9, -2.5),
}
sub = {
    "PASSIVE": "damped, at rest\n(runtime FAULTED)",
    "STAND": "RAMP_IN to home, then\nthe standing policy",
    "POLICY": "a named policy on the\noperator's command",
    "LIE": "hand-over to the lying\npolicy's pose (lie_time)",
    "DAMP": "safe stop: drives damp\n(runtime SAFE_STOP)",
}
fig, ax = plt.subplots(figsize=(10.5, 5.8), dpi=110)
for name, (x, y) in pos.items():
    ax.add_patch(
        FancyBboxPatch(
            (x - 1.0, y - 0.55),
            2.0,
            1.1,
            boxstyle="round,pad=0.05",
            fc={
                "POLICY": "#dcefdc",
                "STAND": "#e3ecf7",
                "PASSIVE": "#eeeeee",
                "LIE": "#f7ecd9",
                "DAMP": "#f6dede",
            }[name],
            ec="#333333",
            lw=1.2,
        )
    )
    ax.text(x, y + 0.22, name, ha="center", va="center", fontsize=12, weight="bold")
    ax.text(x, y - 0.2, sub[name], ha="center", va="center", fontsize=7.5)


def arrow(a, b, label, rad=0.0, dx=0.0, dy=0.0, color="#222222", style="-|>"):
    (x0, y0), (x1, y1) = pos[a], pos[b]
    p = FancyArrowPatch(
        (x0, y0),
        (x1, y1),
        connectionstyle=f"arc3,rad={rad}",
        arrowstyle=style,
        mutation_scale=14,
        lw=1.2,
        color=color,
        shrinkA=38,
        shrinkB=38,
    )
    ax.add_patch(p)
    ax.text(
        (x0 + x1) / 2 + dx,
        (y0 + y1) / 2 + dy,
        label,
        ha="center",
        va="center",
        fontsize=7.5,
        color=color,
        bbox=dict(fc="white", ec="none", pad=0.5),
    )


arrow("PASSIVE", "STAND", "stand\n(right start / reset)", rad=-0.25, dy=0.62)
arrow("STAND", "POLICY", "policy N, next_policy\n(right start; after RAMP_IN)", rad=-0.25, dy=0.62)
arrow("POLICY", "STAND", "stand (all), dead-man", rad=-0.25, dy=-0.62)
px = pos["POLICY"][0]
ax.annotate(
    "",
    xy=(px + 0.8, 0.6),
    xytext=(px - 0.8, 0.6),
    arrowprops=dict(arrowstyle="-|>", connectionstyle="arc3,rad=-1.2", lw=1.2),
)
ax.text(
    px,
    1.6,
    "policy N, next_policy: hand-over\n(right switch; targets blended blend_time)",
    ha="center",
    fontsize=7.5,
)
arrow("POLICY", "LIE", "lie_down (all)", dx=0.5)
arrow("STAND", "LIE", "lie_down", rad=-0.15, dx=0.55, dy=0.1)
arrow("LIE", "STAND", "stand", rad=-0.15, dx=-0.25, dy=-0.25)
arrow("LIE", "DAMP", "lie_time + 0.5 s", dy=0.25)
arrow("STAND", "DAMP", "damp (all)", dx=-0.35, dy=0.2, color="#a02020")
arrow("DAMP", "PASSIVE", "at rest", dx=-0.45)
ax.text(
    3.8,
    -3.75,
    "from STAND, POLICY or LIE: damp (any source), and every safe stop of the runtime\n"
    "(the guard, a fall, stale sensors, over-temperature) -> DAMP; a runtime that resumed by itself\n"
    "or through the ROS 2 node's ~/resume (if authorized) -> STAND",
    ha="center",
    fontsize=7.5,
    color="#a02020",
)
ax.set_xlim(-1.3, 8.9)
ax.set_ylim(-4.2, 2.3)
ax.axis("off")
ax.set_title("The operator's state machine (sim2real.deploy.operator.machine)", fontsize=11)
fig.tight_layout()
fig.savefig("docs/operator_states.png")
