"""Torch state <-> msgpack-able numpy trees (no pickle): the rsl-rl backend's checkpoint contents.

A checkpoint's state is ``ppo_state``'s: the actor's and critic's state dicts, the optimizer's state and the
learning rate (``load_ppo_state`` puts them back, a resume's).
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import torch

__all__ = [
    "load_module_state",
    "load_optimizer_state",
    "load_ppo_state",
    "module_state",
    "optimizer_state",
    "ppo_state",
]


def module_state(module: torch.nn.Module) -> dict[str, np.ndarray]:
    """A module's ``state_dict`` as numpy arrays on the host."""
    return {k: v.detach().cpu().numpy() for k, v in module.state_dict().items()}


def optimizer_state(opt: torch.optim.Optimizer) -> dict[str, Any]:
    """An optimizer's per-parameter state as numpy arrays, its ``param_groups`` as a JSON string."""
    sd = opt.state_dict()
    state = {
        str(pid): {
            k: (v.detach().cpu().numpy() if torch.is_tensor(v) else np.asarray(v)) for k, v in s.items()
        }
        for pid, s in sd["state"].items()
    }
    return {"state": state, "param_groups": json.dumps(sd["param_groups"])}


def load_optimizer_state(opt: torch.optim.Optimizer, data: dict[str, Any], device: str) -> None:
    """Restore ``optimizer_state``'s output into ``opt`` (tensors on ``device``, Adam's ``step`` on CPU)."""
    groups = json.loads(data["param_groups"])
    state = {
        int(pid): {
            k: torch.as_tensor(np.array(v), device="cpu" if k == "step" else device) for k, v in s.items()
        }
        for pid, s in data["state"].items()
    }
    opt.load_state_dict({"state": state, "param_groups": groups})


def load_module_state(module: torch.nn.Module, data: dict[str, Any], device: str) -> None:
    """Restore ``module_state``'s output into ``module`` (tensors on ``device``)."""
    module.load_state_dict({k: torch.as_tensor(np.array(v), device=device) for k, v in data.items()})


def ppo_state(alg: Any) -> dict[str, Any]:
    """What a checkpoint saves of rsl-rl's ``PPO``: actor, critic, optimizer state, learning rate."""
    return {
        "actor": module_state(alg.actor),
        "critic": module_state(alg.critic),
        "optimizer": optimizer_state(alg.optimizer),
        "learning_rate": np.asarray(alg.learning_rate),
    }


def load_ppo_state(alg: Any, state: dict[str, Any], device: str) -> None:
    """Put ``ppo_state``'s output (as read back from a checkpoint) into ``alg``, tensors on ``device``."""
    load_module_state(alg.actor, state["actor"], device)
    load_module_state(alg.critic, state["critic"], device)
    load_optimizer_state(alg.optimizer, state["optimizer"], device)
    alg.learning_rate = float(state["learning_rate"])
