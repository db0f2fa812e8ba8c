"""Where a run's scalars go besides ``metrics.jsonl``: ``--logger tensorboard|wandb|none``.

- ``tensorboard`` (default): event files in ``<run>/tb`` (tensorboardX, imported without torch: the brax
  backend never loads torch). ``tensorboard --logdir runs``.
- ``wandb``: the same event files, and every scalar to a Weights & Biases run named as the run directory
  (project ``--wandb-project``; entity from ``WANDB_ENTITY`` / ``WANDB_USERNAME`` as wandb reads them).
  ``WANDB_MODE=offline`` writes the run under ``<run>/wandb/offline-run-*`` without a network
  (``wandb sync`` uploads it later). wandb is an optional dependency (``pip install 'bar-policy[wandb]'``);
  without it the run is refused at the start, before anything is compiled.
- ``none``: no event files (``metrics.jsonl`` is still written).

Both backends write through the same writer class and the same tags (``log_tags``). The rsl-rl backend
builds it inside rsl-rl's own runner logger (``OnPolicyRunner(..., log_dir=<run>/tb)``, its ``cfg["logger"]``
naming ``WandbWriter`` by path), which also stores the code state rsl-rl records (``tb/git/*.diff``).
Steps: every scalar carries the env step count (wandb: the ``env_steps`` axis, so that the step-0
evaluation written after training does not go back in wandb's own step counter).
"""

from __future__ import annotations

import dataclasses
import importlib.util
import sys
from pathlib import Path
from typing import Any

__all__ = [
    "LOGGERS",
    "WandbWriter",
    "check_logger",
    "make_writer",
    "rsl_rl_logger_cfg",
    "summary_writer_class",
]

LOGGERS: tuple[str, ...] = ("tensorboard", "wandb", "none")
"""The ``--logger`` choices."""

WANDB_MISSING = (
    "--logger wandb needs the wandb package: pip install 'bar-policy[wandb]' (or 'wandb>=0.31,<0.32')"
)


def check_logger(kind: str) -> None:
    """Raise ``ValueError`` (one line naming the choices) for an unknown logger or a missing wandb."""
    if kind not in LOGGERS:
        raise ValueError(f"unknown logger {kind!r}; choices: {', '.join(LOGGERS)}")
    if kind == "wandb" and importlib.util.find_spec("wandb") is None:
        raise ValueError(WANDB_MISSING)


def summary_writer_class() -> type:
    """TensorboardX's ``SummaryWriter``, imported without pulling in torch.

    ``tensorboardX.writer`` runs ``try: import torch`` at import time only to accept torch tensors; we log
    Python floats. Importing torch would bring torch's own CUDA and NCCL libraries into a JAX process (the
    brax backend must not load them), so while tensorboardX is first imported ``import torch`` fails (a
    ``None`` entry in ``sys.modules``, which tensorboardX's ``except ImportError`` handles). When torch is
    already loaded (the rsl-rl backend) the import is left alone.
    """
    if "tensorboardX" not in sys.modules and "torch" not in sys.modules:
        sys.modules["torch"] = None  # type: ignore[assignment]
        try:
            from tensorboardX import SummaryWriter
        finally:
            del sys.modules["torch"]
    from tensorboardX import SummaryWriter

    return SummaryWriter


class WandbWriter:
    """TensorBoard event files in ``log_dir`` and the same scalars in a Weights & Biases run.

    The constructor's keywords are those rsl-rl's runner logger passes a writer named in ``cfg["logger"]``
    (``log_dir`` and the dict's other keys), so one class serves both backends.

    Args:
        log_dir: the event files' directory (``<run>/tb``); the wandb files go to its parent (the run).
        project_name: wandb project.
        run_name: wandb run name (default: the run directory's name).
    """

    def __init__(self, log_dir: str, project_name: str = "bar_policy", run_name: str | None = None) -> None:
        try:
            import wandb
        except ImportError as e:  # check_logger refuses the run before this
            raise ImportError(WANDB_MISSING) from e
        run_dir = Path(log_dir).parent
        self._tb = summary_writer_class()(str(log_dir))
        self._wandb = wandb
        self._run = wandb.init(project=project_name, name=run_name or run_dir.name, dir=str(run_dir))
        self._run.define_metric("env_steps")
        self._run.define_metric("*", step_metric="env_steps")

    def add_scalar(self, tag: str, scalar_value: float, global_step: int | None = None, **_: Any) -> None:
        """One scalar at env step ``global_step``: to the event file and to wandb."""
        self._tb.add_scalar(tag, scalar_value, global_step)
        self._run.log({tag: float(scalar_value), "env_steps": int(global_step or 0)})

    def store_config(self, env_cfg: Any, train_cfg: dict) -> None:
        """The configs into the wandb run's config (what rsl-rl's ``LogWriter`` does)."""
        env = dataclasses.asdict(env_cfg) if dataclasses.is_dataclass(env_cfg) else env_cfg
        self._run.config.update({"train_cfg": train_cfg, "env_cfg": env}, allow_val_change=True)

    def save_file(self, path: str) -> None:
        """A file into the wandb run (rsl-rl's code-state diff)."""
        self._wandb.save(path, base_path=str(Path(path).parent))

    def save_model(self, model_path: str, it: int) -> None:
        """A model file into the wandb run."""
        self.save_file(model_path)

    def save_video(self, video: Any, it: int) -> None:
        """Videos are not logged (no renders during training)."""

    def flush(self) -> None:
        """Flush the event file (wandb streams on its own)."""
        self._tb.flush()

    def stop(self) -> None:
        """Finish the wandb run."""
        if self._run is not None:
            self._run.finish()
            self._run = None

    def close(self) -> None:
        """Close the event file and finish the wandb run."""
        self._tb.close()
        self.stop()


def make_writer(kind: str, log_dir: str | Path, *, project: str = "bar_policy", run_name: str = "") -> Any:
    """The writer for ``--logger kind`` writing into ``log_dir`` (None for ``none``)."""
    check_logger(kind)
    if kind == "none":
        return None
    if kind == "wandb":
        return WandbWriter(str(log_dir), project_name=project, run_name=run_name or None)
    return summary_writer_class()(str(log_dir))


def rsl_rl_logger_cfg(kind: str, *, project: str = "bar_policy", run_name: str = "") -> Any:
    """rsl-rl's ``cfg["logger"]`` for ``--logger kind``: its TensorBoard writer, or ``WandbWriter``."""
    check_logger(kind)
    if kind == "wandb":
        return {
            "class_name": f"{__name__}:WandbWriter",
            "project_name": project,
            "run_name": run_name or None,
        }
    return "tensorboard"
