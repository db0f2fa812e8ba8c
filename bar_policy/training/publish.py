"""Publish a finished run: ONNX + JSON into ``checkpoints/``, the curve PNG and results into ``docs/``.

``publish(run_dir, name="lite_reach_arms")`` copies ``<run>/policy.onnx`` to ``checkpoints/<name>.onnx``
after loading it with the deploy loader (the same checks ``bar-deploy`` runs), writes
``checkpoints/<name>.json`` (config, final evaluation, evaluation history, export record), draws
``docs/training_curve.png`` from ``<run>/metrics.jsonl`` and rewrites the results block of
``docs/reach.md`` (between ``<!-- results:start -->`` and ``<!-- results:end -->``); with
``docs_dir=None`` it writes no docs (the results block and the curve describe the reach policy).
``choose_iterate`` names the file ``publish`` ships, so ``train/ship.py`` can judge that file on held-out data
before anything is written.
"""

from __future__ import annotations

import json
import math
import shlex
import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from bar_policy.provenance import commit_text

__all__ = [
    "ITERATES",
    "RESULTS_END",
    "RESULTS_START",
    "choose_iterate",
    "plot_curve",
    "publish",
    "results_markdown",
]

RESULTS_START = "<!-- results:start -->"
RESULTS_END = "<!-- results:end -->"


def _records(run_dir: Path) -> list[dict[str, Any]]:
    return [json.loads(x) for x in (run_dir / "metrics.jsonl").read_text().splitlines() if x.strip()]


def plot_curve(run_dir: str | Path, out: str | Path, threshold: float = 0.95) -> Path:
    """Training curve PNG: eval success rate and episode reward against env steps and wall time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    run_dir, out = Path(run_dir), Path(out)
    recs = _records(run_dir)
    # In step order: the step-0 evaluation may have run (and been written) last (eval.initial=end).
    ev = sorted((r for r in recs if r["kind"] == "eval"), key=lambda r: r["step"])
    tr = [r for r in recs if r["kind"] == "train"]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    steps = [r["step"] / 1e6 for r in ev]
    ax1.plot(steps, [100 * r["success_rate"] for r in ev], "o-", label="eval success (deterministic)")
    rated = [r for r in tr if "success_rate" in r]  # none before the first segment end (rollout_sums)
    if rated:
        ax1.plot(
            [r["step"] / 1e6 for r in rated],
            [100 * r["success_rate"] for r in rated],
            ".-",
            alpha=0.6,
            label="training success (stochastic)",
        )
    ax1.axhline(100 * threshold, color="gray", ls="--", lw=1, label=f"{100 * threshold:.0f}%")
    ax1.set(xlabel="env steps (M)", ylabel="success rate (%)", ylim=(0, 101), title="Reach success")
    ax1.legend(loc="lower right", fontsize=8)
    if ev:
        top = ax1.secondary_xaxis("top", functions=_time_axis(ev))
        top.set_xlabel("wall time since start (s)")
    ax2.plot(steps, [r["episode_reward"] for r in ev], "o-", label="eval")
    if tr:
        ax2.plot(
            [r["step"] / 1e6 for r in tr],
            [r["episode_reward"] for r in tr],
            ".-",
            alpha=0.6,
            label="training",
        )
    ax2.set(xlabel="env steps (M)", ylabel="episode reward", title="Episode reward")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def _time_axis(ev: list[dict[str, Any]]) -> tuple:
    """Steps (M) <-> wall time (s), interpolated through the evaluations in step order.

    An evaluation that ran after a later step's (the step-0 evaluation after training) is left out: its
    time says when it ran, not when training was there.
    """
    import numpy as np

    times = [r.get("time_s", 0.0) for r in ev]
    ev = [r for i, r in enumerate(ev) if all(times[i] < later for later in times[i + 1 :])]
    s = np.array([r["step"] / 1e6 for r in ev], dtype=float)
    t = np.array([r.get("time_s", 0.0) for r in ev], dtype=float)
    if len(s) < 2 or np.any(np.diff(s) <= 0):
        return (lambda x: x, lambda x: x)
    return (lambda x: np.interp(x, s, t), lambda x: np.interp(x, t, s))


def results_markdown(final: dict[str, Any], name: str) -> str:
    """The results block for docs/reach.md from a run's ``final_eval.json`` content."""
    fe = final["final_eval"]
    dev = final["config"]["device"]
    ttt = final.get("time_to_threshold_s")
    thr = 100 * final.get("success_threshold", 0.95)
    ttt_text = f"{ttt:.0f} s" if ttt is not None else "not reached"
    train = final["config"]["train"]
    # What the final evaluation ran on, as the run summary says it (a run before that record: the count).
    evaluated_on = final.get("final_eval_on") or f"{int(fe.get('episodes', 0))} episodes, randomisation on"
    lines = [
        RESULTS_START,
        f"Shipped policy: `checkpoints/{name}.onnx` (config and evaluation: `checkpoints/{name}.json`).",
        "",
        "| quantity | value |",
        "|---|---|",
        f"| device | {dev['device_kind']} x {len(dev['devices'])} (jax {dev['jax']}) |",
        f"| command | `{_command(final)}` (backend {train['backend']}) |",
        f"| commit | {commit_text(final.get('provenance', {}))} |",
        f"| env steps trained | {final['env_steps']:,} |",
        f"| wall time, start to exported ONNX | {final['wall_s']:.0f} s |",
        f"| time to {thr:.0f}% eval success (compile included) | {ttt_text} |",
        f"| training env steps/s, end to end | {final['train_sps_end_to_end']:,.0f} |",
        f"| final success rate ({evaluated_on}) | {100 * fe['success_rate']:.2f}% |",
        f"| final episode reward | {fe['episode_reward']:.2f} |",
        f"| mean fingertip distance at segment end | {100 * fe['final_distance']:.2f} cm |",
        f"| ONNX parity (max abs error, 4096 obs) | {final['export'].get('max_abs_error', math.nan):.2e} |",
        "",
        "![training curve](training_curve.png)",
        RESULTS_END,
    ]
    return "\n".join(lines)


def _command(final: dict[str, Any]) -> str:
    """The run's exact training command (its provenance), else the preset's command (older runs)."""
    argv = final.get("provenance", {}).get("argv")
    if argv:
        return shlex.join(str(a) for a in argv)
    return f"python train/ppo.py --preset {final['config']['train']['preset']}"


ITERATES = ("last", "best", "auto")
"""Which exported iterate ``publish`` ships: the last one, the best evaluated one (``policy_best.onnx``),
or whichever of the two has the higher-ranked final evaluation (``bar_policy.training.best.score``)."""


def _choose_iterate(final: dict[str, Any], iterate: str, run_dir: Path) -> tuple[Path, dict[str, Any]]:
    """The ONNX file to ship and the record describing it (``final`` with the chosen iterate's figures)."""
    from bar_policy.training.best import best_onnx_path, is_better

    if iterate not in ITERATES:
        raise ValueError(f"iterate must be one of {', '.join(ITERATES)}, got {iterate!r}")
    best = final.get("best_iterate") or {"is_last": True}
    if iterate == "auto":
        better = not best["is_last"] and is_better(best["final_eval"], final["final_eval"])
        iterate = "best" if better else "last"
    if iterate == "last" or best["is_last"]:
        return run_dir / "policy.onnx", {**final, "iterate": "last"}
    src = Path(best.get("onnx") or best_onnx_path(run_dir / "policy.onnx"))
    record = {
        **final,
        "iterate": "best",
        "final_eval": best["final_eval"],
        "env_steps": best["step"],
        "export": best.get("export", {}),
        "last_iterate": {"env_steps": final["env_steps"], "final_eval": final["final_eval"]},
    }
    return src, record


def choose_iterate(run_dir: str | Path, iterate: str = "last") -> tuple[Path, dict[str, Any]]:
    """The ONNX file ``publish(run_dir, iterate=iterate)`` ships, and the record its JSON is made of.

    Raises:
        FileNotFoundError: the run has no ``final_eval.json`` or no such ONNX file (export failed or skipped).
        ValueError: an unknown ``iterate``.
    """
    run_dir = Path(run_dir)
    final_src = run_dir / "final_eval.json"
    if not final_src.exists():
        raise FileNotFoundError(f"{final_src} is missing; did the run finish and export?")
    onnx_src, final = _choose_iterate(json.loads(final_src.read_text()), iterate, run_dir)
    if not onnx_src.exists():
        raise FileNotFoundError(f"{onnx_src} is missing; did the run finish and export?")
    return onnx_src, final


def publish(
    run_dir: str | Path,
    *,
    name: str = "lite_reach_arms",
    checkpoints_dir: str | Path = "checkpoints",
    docs_dir: str | Path | None = "docs",
    iterate: str = "last",
    extra: Mapping[str, Any] | None = None,
) -> dict[str, Path]:
    """Ship a finished run (see the module docstring); returns the written paths.

    Args:
        run_dir: the finished run's directory.
        name: file stem under ``checkpoints_dir``.
        checkpoints_dir: where the ONNX and JSON go.
        docs_dir: where the curve PNG and ``reach.md`` go; None writes no docs (then the returned paths
            are the ONNX and JSON only).
        iterate: ``"last"``, ``"best"`` or ``"auto"`` (see ``ITERATES``). ``"best"`` ships the last iterate
            when the run's best one is the last.
        extra: more top-level entries for the JSON (``train/ship.py``: the ship gate's record).

    Raises:
        FileNotFoundError: the run has no ``policy.onnx`` / ``final_eval.json`` (export failed or skipped).
        ValueError: an unknown ``iterate``.
        bar_policy.deploy.policy.PolicyLoadError: the deploy loader refuses the file.
    """
    from bar_policy.deploy.policy import load_policy

    run_dir = Path(run_dir)
    onnx_src, final = choose_iterate(run_dir, iterate)
    load_policy(onnx_src)  # the checks bar-deploy runs
    ck = Path(checkpoints_dir)
    ck.mkdir(parents=True, exist_ok=True)
    onnx_dst, json_dst = ck / f"{name}.onnx", ck / f"{name}.json"
    shutil.copyfile(onnx_src, onnx_dst)
    record = {"run_dir": str(run_dir), **final, **(extra or {})}
    json_dst.write_text(json.dumps(record, indent=2, sort_keys=True))
    if docs_dir is None:
        return {"onnx": onnx_dst, "json": json_dst}
    docs = Path(docs_dir)
    curve = plot_curve(run_dir, docs / "training_curve.png", final.get("success_threshold", 0.95))
    md = docs / "reach.md"
    block = results_markdown(final, name)
    text = md.read_text() if md.exists() else "# Training\n\n## Results\n\n"
    if RESULTS_START in text and RESULTS_END in text:
        head, rest = text.split(RESULTS_START, 1)
        text = head + block + rest.split(RESULTS_END, 1)[1]
    else:
        text = text.rstrip() + "\n\n## Results\n\n" + block + "\n"
    md.write_text(text)
    return {"onnx": onnx_dst, "json": json_dst, "curve": curve, "docs": md}
