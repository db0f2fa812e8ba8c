"""Torch state <-> msgpack-able numpy trees (no pickle): the rsl-rl backend's checkpoint contents."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import torch

__all__ = ["load_module_state", "load_optimizer_state", "module_state", "optimizer_state"]


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
