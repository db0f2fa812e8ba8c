"""PNG plots of a run log (matplotlib, Agg backend): joints, torques, timing, and tracking for tracking runs.

``plot_log(log, out_dir)`` writes ``joints.png`` (commanded q_cmd vs measured q per joint, and for a
tracking run the reference ``ref_q`` the robot should be at), ``torques.png`` (measured / applied torque
and the host's MIT torque for the command, with the torque cap) and ``timing.png`` (compute and ONNX time
per tick, jitter, overruns, mode). A tracking run (a log with ``ref_q``) also gets ``tracking.png``: the
mean joint error |q - ref_q| (rad) and the fingertip distance to the reference's fingertips (cm, C MuJoCo
kinematics of both), with the mode.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bar_policy.deploy.log.read import load_log

__all__ = ["plot_log", "tracking_errors"]


def _grid(n: int) -> tuple[int, int]:
    cols = 2 if n <= 8 else 3
    return (n + cols - 1) // cols, cols


def _save(fig: Any, path: Path, title: str, **adjust: float) -> Path:
    """Title, margins (``adjust`` overrides the stacked-panels defaults), PNG at 80 dpi, figure closed."""
    import matplotlib.pyplot as plt

    fig.suptitle(title, fontsize=9)
    margins = {"left": 0.1, "right": 0.98, "top": 0.93, "bottom": 0.08, "hspace": 0.25} | adjust
    fig.subplots_adjust(**margins)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def tracking_errors(arrays: dict[str, np.ndarray], mode: str = "arms") -> dict[str, np.ndarray]:
    """Per-tick tracking errors of a tracking run's log (``q`` against ``ref_q``).

    Returns:
        ``joint_error`` (T,) mean |q - ref_q| over joints, rad; ``fingertip_error`` (T, 2) distance of the
        left / right fingertip from the reference pose's, m (C MuJoCo forward kinematics of both).
    """
    from bar_policy.robot.kinematics import Kinematics

    q, ref = arrays["q"], arrays["ref_q"]
    kin = Kinematics(mode)
    tips = np.full((len(q), 2), np.nan)
    for k in range(len(q)):
        if np.isfinite(q[k]).all() and np.isfinite(ref[k]).all():
            tips[k] = [
                np.linalg.norm(a - b)
                for a, b in zip(kin.fingertips(q[k]), kin.fingertips(ref[k]), strict=True)
            ]
    return {"joint_error": np.mean(np.abs(q - ref), axis=1), "fingertip_error": tips}


def plot_log(path: str | Path, out_dir: str | Path | None = None) -> list[Path]:
    """Write the PNG plots of a run log.

    Args:
        path: a run directory or its ``log.npz``.
        out_dir: where to write (default: the run directory).

    Returns:
        The written PNG paths.

    Raises:
        FileNotFoundError: no log at ``path``.
        ValueError: the log has no ticks.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    arrays, meta = load_log(path)
    path = Path(path)
    run_dir = path if path.is_dir() else path.parent
    out = Path(out_dir) if out_dir is not None else run_dir
    out.mkdir(parents=True, exist_ok=True)
    t = arrays.get("t")
    if t is None or t.size == 0:
        raise ValueError(f"run log {path} has no ticks to plot")
    n = arrays["q"].shape[1]
    names = meta.get("joint_names") or [f"joint {i}" for i in range(n)]
    title = f"{meta.get('policy', '?')} on {meta.get('target', '?')}: {meta.get('end_reason', '')}"
    written = []

    rows, cols = _grid(n)

    def joint_grid(series: list[tuple[str, str, str]], label: str, filename: str) -> None:
        """One panel per joint; ``series`` = (array key, line style, legend label), absent keys skipped."""
        fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 1.8 * rows), sharex=True, squeeze=False)
        for i, ax in enumerate(axes.flat):
            if i >= n:
                ax.set_visible(False)
                continue
            for key, style, legend in series:
                if key in arrays:
                    ax.plot(t, arrays[key][:, i], style, label=legend, lw=1.0)
            ax.set_title(names[i], fontsize=8)
            ax.tick_params(labelsize=7)
        axes.flat[0].legend(fontsize=7)
        fig.supxlabel("t (s)", fontsize=8)
        written.append(
            _save(fig, out / filename, f"{label} - {title}", hspace=0.45, wspace=0.15, left=0.05, bottom=0.06)
        )

    joint_grid(
        [("q", "-", "q measured"), ("q_cmd", "--", "q_cmd"), ("ref_q", ":", "reference")],
        "joint positions (rad)",
        "joints.png",
    )
    joint_grid(
        [("tau", "-", "tau measured/applied"), ("tau_cmd", "--", "tau of command")],
        "joint torques (N*m)",
        "torques.png",
    )

    mode_names = {v: k for k, v in (meta.get("mode_names") or {}).items()}

    def mode_axis(ax: object) -> None:
        ax.step(t, arrays["mode"], where="post")  # type: ignore[attr-defined]
        if mode_names:
            ax.set_yticks(sorted(mode_names), [mode_names[k] for k in sorted(mode_names)], fontsize=7)  # type: ignore[attr-defined]
        ax.set_ylabel("mode")  # type: ignore[attr-defined]
        ax.set_xlabel("t (s)")  # type: ignore[attr-defined]

    if "ref_q" in arrays:
        fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
        err = tracking_errors(arrays, meta.get("mode") or "arms")
        axes[0].plot(t, err["joint_error"], lw=0.8, label="mean |q - ref_q|")
        axes[0].set_ylabel("joint error (rad)")
        axes[0].legend(fontsize=7)
        for side, i in (("left", 0), ("right", 1)):
            axes[1].plot(t, 100 * err["fingertip_error"][:, i], lw=0.8, label=f"{side} fingertip")
        axes[1].set_ylabel("fingertip error (cm)")
        axes[1].legend(fontsize=7)
        mode_axis(axes[2])
        written.append(_save(fig, out / "tracking.png", f"tracking - {title}"))

    fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    axes[0].plot(t, arrays["compute"] * 1e3, lw=0.8, label="compute (state->command)")
    if "infer" in arrays:
        axes[0].plot(t, arrays["infer"] * 1e3, lw=0.8, label="ONNX")
    axes[0].set_ylabel("ms")
    axes[0].legend(fontsize=7)
    if "jitter" in arrays:
        axes[1].plot(t, arrays["jitter"] * 1e3, lw=0.8, label="tick start - deadline")
    if "overrun" in arrays and arrays["overrun"].any():
        ov = arrays["overrun"].astype(bool)
        axes[1].plot(t[ov], np.zeros(ov.sum()), "rx", label="overrun")
    axes[1].set_ylabel("jitter (ms)")
    axes[1].legend(fontsize=7)
    mode_axis(axes[2])
    written.append(_save(fig, out / "timing.png", f"timing - {title}"))
    task_name = meta.get("deploy_task")
    if isinstance(task_name, str):  # the task's own plots (the piano roll)
        from bar_policy.deploy.tasks import TASKS, get_task

        if task_name in TASKS:
            written.extend(get_task(task_name).plot(arrays, meta, out))
    return written
