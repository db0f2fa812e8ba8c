"""A run's directory, opened: where it is, its ``config.json``, its logger and the header it prints first.

``open_run`` is ``training.run``'s step between the env build and the trainer: it resolves the directory
(``resolve_run_dir``), makes the run's record (provenance, the training and env configs, the devices),
opens the start-up's executable cache keyed by that record (``startup.session.StartUp.open``), writes
``config.json`` and makes the run's logger (``progress.RunLogger``), which prints the header: the provenance
line, the run line, the settings that differ from the defaults (``run_header``), the start-up's notes.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

from bar_policy.training.config import TrainConfig, config_to_dict
from bar_policy.training.progress import RunLogger
from bar_policy.training.run_header import header_lines
from bar_policy.training.startup.session import StartUp

__all__ = ["open_run", "resolve_run_dir"]


def resolve_run_dir(cfg: TrainConfig, *, check: bool = True) -> Path:
    """``runs_dir/run_name``; an unnamed resume continues in the resumed run's directory.

    ``check=False`` skips the refusal of a used directory (processes other than 0, which write nothing
    and may see process 0's files already).
    """
    if cfg.run_name:
        run_dir = Path(cfg.runs_dir) / cfg.run_name
        if check and not cfg.resume and (run_dir / "metrics.jsonl").exists():
            # Appending a second run to the same metrics.jsonl mixes two curves (seen on a reused machine).
            raise ValueError(
                f"run directory {run_dir} already holds a run; choose another --run-name or --resume it"
            )
        return run_dir
    if cfg.resume:
        p = Path(cfg.resume)
        if p.is_file():
            p = p.parent
        return p.parent if p.name == "checkpoints" else p
    stamp = time.strftime("%Y%m%d-%H%M%S")
    return Path(cfg.runs_dir) / f"{cfg.env_name}-{cfg.backend}-{stamp}"


def _device_record() -> dict[str, Any]:
    """The run's devices, and XLA's flags as the run set them (``backend_env``) as ``xla_flags``.

    The flags choose how the programs run (command buffers, their loops): a speed is read with them.
    """
    import jax

    return {
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.local_devices()],
        "device_kind": jax.local_devices()[0].device_kind,
        "process_count": jax.process_count(),
        "host": platform.node(),
        "jax": jax.__version__,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }


def open_run(cfg: TrainConfig, env: Any, start: StartUp, is_main: bool) -> tuple[Path, RunLogger, dict]:
    """The run directory, its logger and the config record; process 0 writes ``config.json`` and the header.

    The header is the provenance line, the run line and the settings lines (``run_header``), then the
    start-up's notes (``start.notes``) and what opening it did (the autotune seeding waited for, the
    executable cache). Returns ``(run_dir, logger, record)``; the record holds the ``provenance``, the
    ``train`` and ``env`` configs and the ``device``.
    """
    from bar_policy.provenance import collect

    run_dir = resolve_run_dir(cfg, check=is_main)
    provenance = collect()
    record = {
        "provenance": provenance,
        "train": config_to_dict(cfg),
        "env": json.loads(json.dumps(dataclasses.asdict(env.config), default=list))
        if dataclasses.is_dataclass(getattr(env, "config", None))
        else {},
        "device": _device_record(),
    }
    opened = start.open(cfg, record, env)  # the autotune seeding waited for; the executable cache
    header = header_lines(cfg, env, record, run_dir)
    logger = RunLogger(
        run_dir, cfg.ppo.num_timesteps, enabled=is_main, logger=cfg.logger, wandb_project=cfg.wandb_project
    )
    logger.config_record = record  # checkpoint sidecars carry it
    if is_main:
        (run_dir / "config.json").write_text(json.dumps(record, indent=2, sort_keys=True))
    logger.opened(provenance, [*header, *start.notes, *opened])
    return run_dir, logger, record
