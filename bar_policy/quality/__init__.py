"""Safety and smoothness of a policy, and the ship gate.

Completion, torque caps, joint limits, action rate and chatter are defined once for the MJX evaluation,
``bar-deploy`` and the benches (numpy or jax, never torch).
"""

from bar_policy.quality.gate import (
    GateThresholds,
    Miss,
    check,
    excess,
    gate_for,
    gates,
    register_gate,
    score,
    thresholds_text,
)
from bar_policy.quality.metrics import (
    CAP_DWELL_S,
    CAP_FRACTION,
    CHATTER_CUTOFF_HZ,
    LIMIT_MARGIN_RAD,
    action_rate,
    at_cap,
    cap_dwell_step,
    chatter_mrad,
    dwell_exceeded,
    highpass_rms,
    near_limit,
)
from bar_policy.quality.report import EpisodeQuality, QualityMeter, summarise

__all__ = [
    "CAP_DWELL_S",
    "CAP_FRACTION",
    "CHATTER_CUTOFF_HZ",
    "LIMIT_MARGIN_RAD",
    "EpisodeQuality",
    "GateThresholds",
    "Miss",
    "QualityMeter",
    "action_rate",
    "at_cap",
    "cap_dwell_step",
    "chatter_mrad",
    "check",
    "dwell_exceeded",
    "excess",
    "gate_for",
    "gates",
    "highpass_rms",
    "near_limit",
    "register_gate",
    "score",
    "summarise",
    "thresholds_text",
]
