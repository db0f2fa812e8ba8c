"""PNG plots of a run log (matplotlib, Agg backend): joints, torques, timing.

``plot_log(log, out_dir)`` writes ``joints.png`` (commanded q_cmd vs measured q per joint, mode bands),
``torques.png`` (measured / applied torque and the host's MIT torque for the command, with the torque cap)
and ``timing.png`` (compute and ONNX time per tick, jitter, overruns, mode).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bar_policy.deploy.log import load_log

__all__ = ["plot_log"]


def _grid(n: int) -> tuple[int, int]:
    cols = 2 if n <= 8 else 3
    return (n + cols - 1) // cols, cols


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
        fig.suptitle(f"{label} - {title}", fontsize=9)
        fig.supxlabel("t (s)", fontsize=8)
        fig.subplots_adjust(left=0.05, right=0.98, top=0.93, bottom=0.06, hspace=0.45, wspace=0.15)
        written.append(out / filename)
        fig.savefig(written[-1], dpi=80)
        plt.close(fig)

    joint_grid([("q", "-", "q measured"), ("q_cmd", "--", "q_cmd")], "joint positions (rad)", "joints.png")
    joint_grid(
        [("tau", "-", "tau measured/applied"), ("tau_cmd", "--", "tau of command")],
        "joint torques (N*m)",
        "torques.png",
    )

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
    mode_names = {v: k for k, v in (meta.get("mode_names") or {}).items()}
    axes[2].step(t, arrays["mode"], where="post")
    if mode_names:
        axes[2].set_yticks(sorted(mode_names), [mode_names[k] for k in sorted(mode_names)], fontsize=7)
    axes[2].set_ylabel("mode")
    axes[2].set_xlabel("t (s)")
    fig.suptitle(f"timing - {title}", fontsize=9)
    fig.subplots_adjust(left=0.1, right=0.98, top=0.93, bottom=0.08, hspace=0.25)
    written.append(out / "timing.png")
    fig.savefig(written[-1], dpi=80)
    plt.close(fig)
    return written
