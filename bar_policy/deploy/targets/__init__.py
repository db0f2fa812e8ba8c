"""Targets a policy runs on: ``sim`` (C MuJoCo), ``mock`` (no physics), ``real`` (Robstride CAN)."""

from bar_policy.deploy.targets.base import JointState, Target, TargetError

__all__ = ["JointState", "Target", "TargetError"]
