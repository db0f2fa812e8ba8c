"""The published robustness suite: named perturbations a policy is judged on besides the nominal robot.

``bar-deploy eval --perturb suite`` runs every row of ``SUITE`` through the task's evaluation on the sim
target of the perturbed robot and judges each row with the task's ship gate (``quality.gate``), as far as
the row's ``gating`` says:

- ``all``: every threshold of the gate (the nominal gate, unchanged);
- ``safety``: completion and torque caps only (pushes: the error and the chatter during a push are
  reported, not judged);
- ``none``: reported, not judged (an encoder offset: a calibration error is invisible to any policy).
"""

from __future__ import annotations

from dataclasses import dataclass

from bar_policy.robot.perturb_spec import Perturbation, parse_perturbation

__all__ = ["GATINGS", "SUITE", "SuiteRow"]

GATINGS = ("all", "safety", "none")
"""How much of the gate judges a row (module docstring)."""


@dataclass(frozen=True)
class SuiteRow:
    """One row of the suite: a name for the table, the spec, how the gate judges it."""

    name: str
    spec: str
    """``KEY=VALUE,...`` (``robot.perturb_spec``); empty: the nominal robot."""
    gating: str = "all"

    def __post_init__(self) -> None:
        if self.gating not in GATINGS:
            raise ValueError(f"suite row {self.name!r}: gating {self.gating!r} not in {list(GATINGS)}")

    @property
    def perturbation(self) -> Perturbation:
        """The parsed spec."""
        return parse_perturbation(self.spec)


SUITE: tuple[SuiteRow, ...] = (
    SuiteRow("nominal", ""),
    SuiteRow("mass x0.8", "mass_scale=0.8"),
    SuiteRow("mass x1.2", "mass_scale=1.2"),
    SuiteRow("payload 0.5 kg fingertip", "payload_kg=0.5,payload_at=fingertip"),
    SuiteRow("payload 0.5 kg palm", "payload_kg=0.5,payload_at=palm"),
    SuiteRow("friction +1.0 N*m", "friction_nm=1.0"),
    SuiteRow("damping +1.0 N*m*s/rad", "damping=1.0"),
    SuiteRow("strength x0.8", "strength=0.8"),
    SuiteRow("action delay 2 ticks", "action_delay_ticks=2"),
    SuiteRow("obs delay 1 tick", "obs_delay_ticks=1"),
    SuiteRow("offset 0.01 rad", "offset_rad=0.01", gating="none"),
    SuiteRow("push 10 N", "push_n=10", gating="safety"),
    SuiteRow(
        "combined",
        "mass_scale=1.1,payload_kg=0.3,payload_at=fingertip,friction_nm=0.5,strength=0.9,"
        "action_delay_ticks=1,offset_rad=0.002",
    ),
)
"""The suite, nominal first (the ratios' reference)."""
