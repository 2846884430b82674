"""The operator's state machine (:class:`OperatorMachine`) around one runtime.

States: ``PASSIVE`` (damped, lying or held at rest: the runtime FAULTED after a stop), ``STAND``
(the runtime's RAMP_IN to the home pose, then the standing policy, or the walking one at a zero
command where the run has no standing policy), ``POLICY`` (a named policy RUNNING on the
operator's command), ``LIE`` (the hand-over to the lying policy: the targets ramp to its folded
pose over ``lie_time``, then DAMP), ``DAMP`` (a stop under way: the runtime's SAFE_STOP, which
lays a legged robot down damped). Transitions, each logged with its time, cause and requester:

- ``stand``: PASSIVE -> STAND (the runtime's ``reset_faults``: RAMP_IN from the measured pose;
  right ``start`` after an operator's stop, ``reset`` after a fault of another cause);
  POLICY -> STAND (open to all, as a stop is: it only slows the robot down).
- a policy (``policies`` / ``next_policy``): STAND -> POLICY (right ``start``; once RAMP_IN
  ended), POLICY -> POLICY (right ``switch``; the hand-over blends the targets,
  :meth:`Runtime.switch_policy <sim2real.deploy.runtime.loop.Runtime.switch_policy>`).
- ``damp``: STAND, POLICY or LIE -> DAMP (open to all); DAMP -> PASSIVE once at rest.
- ``lie_down``: STAND or POLICY -> LIE (open to all; without a lying policy: DAMP); LIE -> DAMP
  ``lie_time`` + ``LIE_SETTLE`` s later; LIE -> STAND on ``stand``.
- the runtime's own stops override everything: any safe stop (the guard's, a fall, stale
  sensors) moves STAND or POLICY to DAMP, its cause logged; a runtime that resumed by itself
  (a cooled winding) or through the ROS 2 node moves PASSIVE or DAMP to STAND.
- the dead-man: no frame for ``deadman.timeout`` s: the command ramps to zero; for
  ``stand_after`` s more: POLICY -> STAND.

Requests refused (a transition from a state where it is not safe, a requester without the
right) are logged too. One robot (``envs`` 1).
"""

from __future__ import annotations

import sys
from dataclasses import asdict, dataclass

import numpy as np

from sim2real.deploy.core.modes import FAULTED, RAMP_IN, RUNNING, SAFE_STOP
from sim2real.deploy.operator.mapping import COMPONENTS, Mapping, split_combo
from sim2real.deploy.tasks.heading import HeadingHold

PASSIVE, STAND, POLICY, LIE, DAMP = "PASSIVE", "STAND", "POLICY", "LIE", "DAMP"
STATES = (PASSIVE, STAND, POLICY, LIE, DAMP)
#: s the robot rests on the lying policy's pose before the drives damp (our choice: a quarter
#: of the 2-s ramp, for the body to settle on the floor).
LIE_SETTLE = 0.5
_UP = (STAND, POLICY, LIE)  # states with the runtime running a policy


@dataclass(frozen=True)
class Transition:
    """One logged event: ``t`` s (the run's time), ``state`` -> ``to`` (equal for a refusal),
    the policy in control after it, its ``cause``, the ``requester`` (a source, ``ros2``,
    ``runtime``, ``deadman``) and, for a refused request, ``refused`` (why)."""

    t: float
    state: str
    to: str
    policy: str
    cause: str
    requester: str
    refused: str | None = None


class OperatorMachine:
    """The state machine (module docstring) over ``runtime``.

    Args:
        runtime: The :class:`~sim2real.deploy.runtime.Runtime` (one env), started or about to be;
            its policy is ``policies[first]``.
        policies: Policy name -> policy (``OnnxPolicy``), in the run's order; the first is the
            runtime's at the start.
        mapping: The :class:`~sim2real.deploy.operator.mapping.Mapping`.
        sources: The :class:`~sim2real.deploy.operator.frame.OperatorInput` s to poll.
        stand_policy: The name of the standing policy (absent from ``policies``: STAND runs the
            walking policy at a zero command).
        lie_policy: The name of the lying policy (absent: ``lie_down`` damps at once).
        log: A function given each transition's line (default: print to stderr).

    Raises:
        ValueError: more than one env; a mapping naming a standing policy that is the only one.
    """

    def __init__(
        self,
        runtime,
        policies: dict,
        mapping: Mapping,
        sources,
        stand_policy: str = "stand",
        lie_policy: str = "lie",
        log=None,
    ):
        if runtime.envs != 1:
            raise ValueError(f"the operator drives one robot: --envs must be 1, got {runtime.envs}")
        self.rt, self.policies, self.mapping, self.sources = (
            runtime,
            dict(policies),
            mapping,
            list(sources),
        )
        self.stand_name = stand_policy if stand_policy in self.policies else None
        self.lie_name = lie_policy if lie_policy in self.policies else None
        self.walk_names = [n for n in self.policies if n not in (self.stand_name, self.lie_name)]
        self._lie_at = 0.0
        self._from_floor = False
        if not self.walk_names:
            raise ValueError(
                f"the run has no walking policy besides '{stand_policy}', '{lie_policy}'"
            )
        self.active = next(iter(self.policies))
        self.state = STAND
        self.log: list[Transition] = []
        self._print = log or (lambda line: print(line, file=sys.stderr, flush=True))
        self.command = np.zeros(3)
        self._keys = np.zeros(3)
        self._hold = None
        if mapping.command.heading_hold > 0 and runtime.base_estimator is not None:
            self._hold = HeadingHold(1, gain=mapping.command.heading_hold)
        self._held: dict[int, frozenset[str] | None] = {i: None for i in range(len(self.sources))}
        self._heard = -np.inf
        self.switches = 0
        self.deadman_events = 0
        self._deadman_fired = False
        combos = {f"action:{k}": v for k, v in mapping.actions.items()}
        combos.update({f"policy:{k}": v for k, v in mapping.policies.items() if k in self.policies})
        # the longest combinations first: "L1+start" takes its buttons before "start" may fire
        self._combos = sorted(
            ((split_combo(c), a) for a, c in combos.items()), key=lambda x: -len(x[0])
        )
        self.unknown_policies = sorted(set(mapping.policies) - set(self.policies))

    # ------------------------------------------------------------------ the record
    def _note(self, to: str, cause: str, requester: str, refused: str | None = None) -> None:
        tr = Transition(
            round(self.rt.time, 4), self.state, to, self.active, cause, requester, refused
        )
        self.log.append(tr)
        if refused is None:
            self.state = to
            line = f"operator: t={tr.t:.2f} s {tr.state} -> {to} ({cause}; {requester}; policy {self.active})"
        else:
            line = f"operator: t={tr.t:.2f} s refused {cause} from {requester} in {tr.state}: {refused}"
        self._print(line)
        telemetry = self.rt.telemetry
        if telemetry is not None and hasattr(telemetry, "event"):
            telemetry.event("/operator", self.rt.time, asdict(tr))

    def may(self, right: str, requester: str) -> bool:
        """Whether ``requester`` holds ``right`` (the mapping's authority table)."""
        return requester in self.mapping.allowed(right)

    # ------------------------------------------------------------------ each tick
    def start(self) -> None:
        """The run started (RAMP_IN): STAND, or PASSIVE (damped) when the mapping says so."""
        self._note(STAND, "runtime started (RAMP_IN to home)", "runtime")
        if self.mapping.start == "passive":
            self.request("damp", "runtime", cause="start passive")

    def step(self, now: float) -> None:
        """Poll the sources, follow the runtime's own transitions, act on the buttons pressed,
        write the velocity command (runtime.velocity_command, m/s and rad/s)."""
        frames = []
        for src in self.sources:
            frame = src.poll(now)
            frames.append(frame)
            if frame is not None:
                self._heard = max(self._heard, frame.stamp)
        self.sync()
        for i, (src, frame) in enumerate(zip(self.sources, frames, strict=True)):
            if frame is not None:
                for action in self._edges(i, frame):
                    self.request(action, src.source)
        self._command(frames, now)
        self._expect_low()

    def _edges(self, i: int, frame) -> list[str]:
        """The actions whose combination became complete in ``frame`` (rising edges); a
        source's first frame only sets what is held (a button held at start does nothing)."""
        prev = self._held[i]
        down = frame.buttons | frame.presses
        self._held[i] = frame.buttons
        if prev is None:  # held when first heard: not pressed (a key tapped since still is)
            prev = frame.buttons
        fired, used = [], set()
        for combo, action in self._combos:
            if all(b in down for b in combo) and not all(b in prev for b in combo):
                if used.isdisjoint(combo):
                    fired.append(action)
                    used.update(combo)
        return sorted(fired, key=lambda a: a != "action:damp")  # a stop first

    def sync(self) -> None:
        """Follow the runtime: its stops override (STAND/POLICY -> DAMP), DAMP -> PASSIVE at
        rest, a runtime resumed by itself or by the ROS 2 node -> STAND."""
        if self.state == LIE and self.rt.time - self._lie_at >= self.mapping.lie_time + LIE_SETTLE:
            self.rt.supervision.safe_stop(np.ones(1, dtype=bool), "operator")
            self._note(DAMP, "lain down", "runtime")
        m = int(self.rt.mode[0])
        if m in (SAFE_STOP, FAULTED) and self.state in _UP:
            self._note(DAMP, f"runtime safe stop: {self.rt.cause_names()[0]}", "runtime")
        if self.state == DAMP and m == FAULTED:
            self._note(PASSIVE, f"at rest, damped (cause {self.rt.cause_names()[0]})", "runtime")
        if self.state in (PASSIVE, DAMP) and m in (RAMP_IN, RUNNING):
            self._note(STAND, "runtime resumed", "runtime")
            self._from_floor = True

    def _expect_low(self) -> None:
        """Tell the runtime where a low base is asked for: lying down, or standing up from the
        floor (RAMP_IN after PASSIVE); there only a tilt is a fall."""
        m = int(self.rt.mode[0])
        if m != RAMP_IN:
            self._from_floor = False
        self.rt.lying_expected[:] = self.state == LIE or (self._from_floor and m == RAMP_IN)

    # ------------------------------------------------------------------ requests
    def request(self, action: str, requester: str, cause: str | None = None) -> tuple[bool, str]:
        """Ask for ``action`` (``action:stand``, ``action:damp``, ``action:next_policy``,
        ``policy:<name>``; the bare names too) as ``requester``; (done, message), each logged."""
        if ":" not in action:
            action = f"action:{action}"
        kind, _, name = action.partition(":")
        cause = cause or (name if kind == "action" else f"policy {name}")
        if name == "damp":
            return self._damp(requester, cause)
        if name == "lie_down":
            return self._lie(requester, cause)
        if name == "stand":
            return self._stand(requester, cause)
        if name == "next_policy":
            i = self.walk_names.index(self.active) + 1 if self.active in self.walk_names else 0
            if self.state == POLICY:
                name = self.walk_names[i % len(self.walk_names)]
            else:
                name = self.walk_names[0]
            return self._policy(name, requester, cause)
        if kind == "policy":
            return self._policy(name, requester, cause)
        return self.refuse(cause, requester, f"unknown request '{action}'")

    def refuse(self, cause: str, requester: str, why: str) -> tuple[bool, str]:
        """Log a refused request (``cause`` what was asked, ``why`` not); ``(False, why)``."""
        self._note(self.state, cause, requester, refused=why)
        return False, why

    def _lie(self, requester: str, cause: str) -> tuple[bool, str]:
        if self.lie_name is None:
            return self._damp(requester, cause)
        if self.state not in (STAND, POLICY) or int(self.rt.mode[0]) != RUNNING:
            return self.refuse(cause, requester, f"in {self.state}: not standing or walking")
        self._select(self.lie_name, blend=True, blend_time=self.mapping.lie_time)
        self._lie_at = self.rt.time
        self._note(LIE, cause, requester)
        return True, "lying down"

    def _damp(self, requester: str, cause: str) -> tuple[bool, str]:
        if self.state not in _UP:
            return self.refuse(cause, requester, f"already {self.state.lower()}")
        self.rt.supervision.safe_stop(np.ones(1, dtype=bool), "operator")
        self._note(DAMP, cause, requester)
        return True, "damping (safe stop, cause operator)"

    def _stand(self, requester: str, cause: str) -> tuple[bool, str]:
        if self.state == PASSIVE:
            operator_stop = self.rt.cause_names()[0] in ("operator", None)
            right = "start" if operator_stop else "reset"
            if not self.may(right, requester):
                return self.refuse(cause, requester, f"'{requester}' lacks the right '{right}'")
            self._select(self.stand_name or self.active, blend=False)
            self.rt.reset_faults()
            self.rt.ramp_in(self.mapping.stand_time)  # slowly, as the bring-up's ramp
            self._from_floor = True
            self._note(STAND, cause, requester)
            return True, "standing up (RAMP_IN)"
        if self.state in (POLICY, LIE):
            if self.stand_name is not None:
                self._select(self.stand_name, blend=True)
            self._note(STAND, cause, requester)
            return True, "standing"
        return self.refuse(
            cause,
            requester,
            f"in {self.state}: "
            + ("already standing" if self.state == STAND else "still stopping: wait until at rest"),
        )

    def _policy(self, name: str, requester: str, cause: str) -> tuple[bool, str]:
        if name not in self.policies:
            return self.refuse(cause, requester, f"no policy '{name}' in this run")
        if self.state not in (STAND, POLICY):
            return self.refuse(cause, requester, f"in {self.state}: stand first")
        if int(self.rt.mode[0]) != RUNNING:
            return self.refuse(cause, requester, "still standing up (RAMP_IN)")
        right = "start" if self.state == STAND else "switch"
        if not self.may(right, requester):
            return self.refuse(cause, requester, f"'{requester}' lacks the right '{right}'")
        if self.state == POLICY and name == self.active:
            return self.refuse(cause, requester, f"'{name}' is in control already")
        self._select(name, blend=True)
        self._note(POLICY, cause, requester)
        return True, f"policy {name}"

    def _select(self, name: str, blend: bool, blend_time: float | None = None) -> None:
        """Hand the runtime to policy ``name`` (no switch when it is in control already)."""
        policy = self.policies[name]
        if policy is not self.rt.policy:
            t = self.mapping.blend_time if blend_time is None else blend_time
            self.rt.switch_policy(policy, t if blend else 0.0)
            self.switches += 1
        self.active = name

    # ------------------------------------------------------------------ the command
    def _command(self, frames, now: float) -> None:
        cfg, dt = self.mapping.command, self.rt.dt
        target = np.zeros(3)
        rate = np.full(3, cfg.rate_limit)
        silent = now - self._heard
        dead = silent > self.mapping.deadman.timeout
        if self.state == POLICY and not dead:
            frame = max((f for f in frames if f is not None), key=lambda f: f.stamp, default=None)
            for k, c in enumerate(COMPONENTS):
                axis = getattr(cfg, c)
                if axis is not None and frame is not None:
                    v = frame.axes.get(axis.axis, 0.0)
                    shaped = (
                        0.0
                        if abs(v) <= axis.deadband
                        else np.sign(v) * (abs(v) - axis.deadband) / (1 - axis.deadband)
                    )
                    target[k] = axis.scale * shaped
                    rate[k] = axis.rate_limit
            for f in frames:
                for key in f.presses if f is not None else ():
                    if key in cfg.keys:
                        comp, step = cfg.keys[key]
                        if step == 0:
                            self._keys[:] = 0.0
                        else:
                            k = COMPONENTS.index(comp)
                            lim = cfg.limit.get(comp, np.inf)
                            self._keys[k] = np.clip(self._keys[k] + step, -lim, lim)
            target += self._keys
        else:
            self._keys[:] = 0.0
        if dead and self.state == POLICY and not self._deadman_fired:
            self._deadman_fired = True
            self.deadman_events += 1
            self._print(
                f"operator: t={self.rt.time:.2f} s dead-man: no input for {silent:.2f} s, command to zero"
            )
        if not dead:
            self._deadman_fired = False
        if (
            dead
            and self.state == POLICY
            and silent > self.mapping.deadman.timeout + self.mapping.deadman.stand_after
        ):
            self._stand("deadman", f"dead-man: no input for {silent:.1f} s")
        self.command += np.clip(target - self.command, -rate * dt, rate * dt)
        self.rt.velocity_command[:] = self.command
        if self._hold is not None:
            if self.state == POLICY:  # a centred yaw stick holds the heading
                self._hold(self.rt, self.command[None, :])
            else:
                self._hold.holding[:] = False
