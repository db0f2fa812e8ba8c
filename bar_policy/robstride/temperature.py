"""Host-side over-temperature watch: per-model warning and fault thresholds on the feedback temperature.

Every type-2 reply carries a temperature (bytes 6-7, degC x 10; robstride-protocol.md section 3; which
sensor it is, winding or MOSFET, is not stated). The firmware acts on its own over-temperature threshold
(fault bit 18, which the driver already refuses); the host acts earlier, on the thresholds below, so that the
runtime can damp and stop in a controlled way before the firmware cuts the torque mid-motion.

Thresholds (degC; robstride-protocol.md section 6.2, "Default over-temperature fault / warning thresholds per
manual sections 4.1.8-4.1.10", and the MIT chapter's single "fault 130" for all models):

- fault = min(the model's firmware fault threshold, 130): the reference marks the thresholds [CONFLICT]
  between chapters, so the lower (the MIT chapter's 130) is taken where they differ.
- warning = min(the model's firmware warning threshold, fault - 10): for rs-02, rs-05 and rs-06 the manual
  gives warning = fault (135 / 135), i.e. no warning band; the 10 degC band is the one the manual gives
  for rs-00, rs-01, rs-03 and rs-04 (145 / 135, 103 / 93).

So rs-01: 93 / 103; every other model: 120 / 130 (warning / fault). A reading at or above the warning
threshold is counted and logged once per joint (with the count so far, and again in ``summary``); a reading
at or above the fault threshold is a fault (``TemperatureMonitor.check`` returns it). Missing readings (NaN)
are ignored.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "FIRMWARE_THRESHOLDS",
    "MIT_CHAPTER_FAULT",
    "WARNING_BAND",
    "TemperatureLimits",
    "TemperatureMonitor",
    "temperature_limits",
]

log = logging.getLogger(__name__)

FIRMWARE_THRESHOLDS: dict[str, tuple[float, float]] = {
    "rs-00": (145.0, 135.0),
    "rs-01": (103.0, 93.0),
    "rs-02": (135.0, 135.0),
    "rs-03": (145.0, 135.0),
    "rs-04": (145.0, 135.0),
    "rs-05": (135.0, 135.0),
    "rs-06": (135.0, 135.0),
}
"""Model -> the firmware's default (fault, warning) over-temperature thresholds, degC (reference 6.2)."""
MIT_CHAPTER_FAULT = 130.0
"""The manuals' MIT chapter's over-temperature fault threshold, all models, degC (reference 6.2)."""
WARNING_BAND = 10.0
"""Warning this far below the fault threshold where the manual gives no band, degC (module docstring)."""


@dataclass(frozen=True, slots=True)
class TemperatureLimits:
    """Host-side thresholds of one model, degC: a reading at or above ``warning`` warns, ``fault`` faults."""

    warning: float
    fault: float


def temperature_limits(model: str) -> TemperatureLimits:
    """The host-side thresholds of a Robstride model (module docstring); ``KeyError`` for an unknown model."""
    try:
        fw_fault, fw_warning = FIRMWARE_THRESHOLDS[model]
    except KeyError as exc:
        raise KeyError(
            f"no temperature thresholds for model {model!r}; known: {sorted(FIRMWARE_THRESHOLDS)}"
        ) from exc
    fault = min(fw_fault, MIT_CHAPTER_FAULT)
    return TemperatureLimits(warning=min(fw_warning, fault - WARNING_BAND), fault=fault)


class TemperatureMonitor:
    """Watches the feedback temperatures of joints (canonical order) against their models' limits."""

    def __init__(self, joint_names: Sequence[str], models: Sequence[str]) -> None:
        if len(joint_names) != len(models):
            raise ValueError(f"{len(joint_names)} joints but {len(models)} models")
        self.joint_names = tuple(joint_names)
        self.limits = tuple(temperature_limits(m) for m in models)
        self.warning = np.array([lim.warning for lim in self.limits])
        """Warning threshold per joint, degC."""
        self.fault = np.array([lim.fault for lim in self.limits])
        """Fault threshold per joint, degC."""
        self.warning_counts = np.zeros(len(self.joint_names), dtype=np.int64)
        """Readings at or above the warning threshold, per joint."""
        self.fault_counts = np.zeros(len(self.joint_names), dtype=np.int64)
        """Readings at or above the fault threshold, per joint."""
        self.max_seen = np.full(len(self.joint_names), np.nan)
        """Highest temperature read per joint, degC (NaN before any reading)."""
        self.last = np.full(len(self.joint_names), np.nan)
        """The latest temperature per joint, degC (NaN where the latest reading had no reply)."""

    def check(self, temperature: np.ndarray) -> tuple[str, ...]:
        """Take one reading (degC per joint; NaN = missing); returns a description per joint at fault level.

        The first reading of a joint at or above its warning threshold is logged as a warning.
        """
        t = np.asarray(temperature, dtype=np.float64)
        self.last = t.copy()
        seen = np.isfinite(t)
        self.max_seen = np.where(seen & ~(self.max_seen >= t), t, self.max_seen)
        hot = seen & (t >= self.warning)
        faulted = seen & (t >= self.fault)
        first = hot & (self.warning_counts == 0)
        self.warning_counts += hot
        self.fault_counts += faulted
        for i in np.flatnonzero(first):
            log.warning(
                "%s: temperature %.1f degC at or above the %g degC warning threshold (fault at %g degC); "
                "warned once per joint, counted (1 reading so far)",
                self.joint_names[i],
                t[i],
                self.warning[i],
                self.fault[i],
            )
        return tuple(
            f"{self.joint_names[i]}: over-temperature {t[i]:.1f} degC >= {self.fault[i]:g} degC (host limit)"
            for i in np.flatnonzero(faulted)
        )

    def counts(self) -> dict[str, int]:
        """Joint -> readings at or above its warning threshold (joints with none are absent)."""
        return {n: int(c) for n, c in zip(self.joint_names, self.warning_counts, strict=True) if c}

    def summary(self) -> str:
        """One line: each joint that reached its warning threshold, its count and highest reading."""
        parts = [
            f"{n}: {int(c)} readings >= {w:g} degC (max {m:.1f})"
            for n, c, w, m in zip(
                self.joint_names, self.warning_counts, self.warning, self.max_seen, strict=True
            )
            if c
        ]
        return "; ".join(parts) if parts else "no joint reached its temperature warning threshold"
