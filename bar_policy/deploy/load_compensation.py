"""What a run adds to ``tau_ff`` for the load at the hands: the fit's gravity torque and the load's inertia.

Both are chosen per run and scheduled by the runtime's mode.

- The fit (``deploy.hand_load``; ``RuntimeConfig.hand_load``, else the command source's): ``estimate`` fits
  on every POLICY tick once a command has been written (before it the torque is no command's: a reset's
  0); ``tare`` only on the source's still start (``CommandSource.still_s``: the piano's count-in), then
  keeps that estimate, and on a start through HOLD also on the still ticks after the ramp
  (``RuntimeConfig.start_tare_s``: the runtime says which with ``still``), feeding it forward as it goes, so
  the count-in fits on from an arm already lifted off whatever it sagged onto; ``off``: none. Left off,
  saying why, on a target whose torque is no motor's (``Target.measures_torque``: the mock, a dry run). The
  end's HOLD keeps the last estimate (no fit: the arm no longer follows the policy).
- The load's inertia (``deploy.load_inertia``; ``RuntimeConfig.load_inertia``, else the source's): in POLICY,
  the fit's masses times the reference arm's acceleration, the reference started on POLICY's first tick and
  fed each command before any load feed-forward. It needs the fit.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

from bar_policy.deploy.hand_load import HandLoadEstimator
from bar_policy.deploy.load_inertia import LoadInertia
from bar_policy.deploy.safety import Mode

if TYPE_CHECKING:
    from bar_policy.deploy.run_config import RuntimeConfig
    from bar_policy.deploy.targets.base import JointState, Target
    from bar_policy.robot.mit import MitCommand
    from bar_policy.tasks.interfaces import CommandSource

__all__ = ["LoadCompensation"]

log = logging.getLogger(__name__)


class LoadCompensation:
    """One run's hand-load fit and load-inertia feed-forward (module docstring); called once per tick."""

    def __init__(self, config: RuntimeConfig, commands: CommandSource, target: Target, mode: str) -> None:
        """Choose both for ``commands`` on ``target`` (robot ``mode``).

        Raises ``ValueError`` for ``tare`` on a source without a still start and for the inertia asked for
        with the fit off, each naming what works.
        """
        dt = config.control_dt
        self.kind = config.hand_load or commands.hand_load
        """``estimate``, ``tare`` or ``off``, and why when a requested fit was left off (run log)."""
        self.tare_ticks: int | None = None
        """``tare``: how many POLICY ticks fit, the source's still start; None: every tick or no fit."""
        self.fit: HandLoadEstimator | None = None
        """The hand-load fit (None: off)."""
        self.policy_fits = 0
        """POLICY ticks fitted (``tare``: at most ``tare_ticks``)."""
        self.start_fits = 0
        """HOLD ticks fitted before POLICY (``tare`` on a start through HOLD)."""
        if self.kind == "tare":
            self.tare_ticks = round(commands.still_s / dt)
            if self.tare_ticks < 1:
                raise ValueError(
                    f"hand-load tare needs a still start and {type(commands).__name__} has "
                    f"{commands.still_s:g} s (CommandSource.still_s); valid here: estimate or off"
                )
        if self.kind != "off":
            if target.applies_commands and target.measures_torque:
                self.fit = HandLoadEstimator(mode, dt)
            else:
                self.kind = f"off (asked {self.kind}; {type(target).__name__} measures no applied torque)"
                self.tare_ticks = None
                log.warning("hand-load compensation left off: %s", self.kind)
        asked = config.load_inertia
        want = commands.load_inertia if asked is None else asked
        self.inertia_kind = "on" if want else "off"
        """``on`` or ``off``, and why when a wanted feed-forward was left off (run log)."""
        self.inertia: LoadInertia | None = None
        """The reference arm and the inertia feed-forward (None: off)."""
        if want and self.fit is None:
            if asked and self.kind == "off":
                raise ValueError(
                    "load inertia on needs the hand-load fit's mass: hand load must be estimate or tare "
                    "(got off); or load inertia off"
                )
            self.inertia_kind = f"off (wanted; hand-load {self.kind})"
        elif want:
            self.inertia = LoadInertia(mode, dt, commands.reference_scene)

    @property
    def start_tare(self) -> bool:
        """The fit tares: a start through HOLD holds still for it after the ramp (``start_tare_s``)."""
        return self.fit is not None and self.tare_ticks is not None

    def __call__(
        self, cmd: MitCommand, state: JointState, mode: Mode, *, commanded: bool, still: bool = False
    ) -> MitCommand:
        """``cmd`` with the loads' feed-forward added to ``tau_ff`` (module docstring).

        ``state``: this tick's reading; ``mode``: the supervisor's mode for this tick; ``commanded``: a
        command has been written before this tick; ``still``: a HOLD tick of the start's still dwell after
        the ramp (``RuntimeConfig.start_tare_s``), where ``tare`` fits.
        """
        fit = self.fit
        if fit is None:
            return cmd
        if still and mode == Mode.HOLD and commanded and self.start_tare:
            self.start_fits += 1
            return cmd._replace(tau_ff=cmd.tau_ff + fit.step(state.q, state.tau))
        nominal = cmd
        fitting = self.tare_ticks is None or self.policy_fits < self.tare_ticks
        if mode == Mode.POLICY and commanded and fitting:
            self.policy_fits += 1
            cmd = cmd._replace(tau_ff=cmd.tau_ff + fit.step(state.q, state.tau))
        elif mode in (Mode.POLICY, Mode.HOLD) and fit.updates:  # tare's kept estimate, the end's HOLD
            cmd = cmd._replace(tau_ff=cmd.tau_ff + fit.torque(state.q))
        inertia = self.inertia
        if inertia is not None and mode == Mode.POLICY:
            if not inertia.started:
                inertia.start(state.q, state.dq)
            cmd = cmd._replace(tau_ff=cmd.tau_ff + inertia.step(nominal, state.q, fit.masses))
        return cmd

    def record(self) -> dict[str, Any]:
        """For the run log: the fit's kind and, when on, its record; the inertia's kind and record."""
        rec: dict[str, Any] = {"kind": self.kind}
        if self.tare_ticks is not None:
            rec["tare_ticks"] = self.tare_ticks
            rec["start_tare_ticks"] = self.start_fits
        if self.fit is not None:
            rec.update(self.fit.record())
        rec["load_inertia"] = {"kind": self.inertia_kind}
        if self.inertia is not None:
            rec["load_inertia"].update(self.inertia.record())
        return rec
