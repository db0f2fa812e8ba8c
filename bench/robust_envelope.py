"""Robustness envelope of a policy file: its task metric against each perturbation's magnitude, one PNG.

Each perturbation key of the robustness suite (``robot/perturb_suite.py``) is swept over a range of
magnitudes (``SWEEPS``: the suite's value inside it, and beyond it on both sides where the key allows), each
point the task's whole evaluation on the perturbed sim target (``deploy.robustness.run_suite``, the code
path of ``bar-deploy eval --perturb``), judged by the task's ship gate as the suite judges that key (an
encoder offset is reported, not judged; pushes on completion and caps). The figure has one panel per key:
the task's accuracy figure (``PLOTTED``: the suite table's first metric) against the magnitude, the nominal
robot ringed, the gate's threshold drawn (reach: the median segment-end distance's), each point the gate
misses (on any threshold) a red cross.

    python bench/robust_envelope.py --policy checkpoints/lite_reach_arms.onnx --out docs/envelope_reach.png
    python bench/robust_envelope.py --policy checkpoints/lite_track_arms.onnx --out docs/envelope_track.png
    python bench/robust_envelope.py --policy checkpoints/lite_piano_arms.onnx --out docs/envelope_piano.png \
        --random-songs 0

``--keys`` picks sweeps (default all), ``--json FILE`` keeps every point's figures; the task's eval options
(``--episodes``, ``--clips``, ``--songs``, ``--random-songs``) pass through as ``bar-deploy eval`` takes
them, the same for every point.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bar_policy.quality.gate import gate_for
from bar_policy.robot.perturb_suite import SuiteRow


@dataclass(frozen=True)
class Sweep:
    """One key's magnitudes: ``KEY=VALUE`` specs (with ``extra``) and the nominal robot's value of the key."""

    key: str
    values: tuple[float, ...]
    nominal: float
    unit: str
    extra: str = ""
    """Fixed ``KEY=VALUE`` pairs every point carries (``payload_at=fingertip``)."""
    gating: str = "all"
    """As the suite's row of the key (``perturb_suite.GATINGS``)."""

    def rows(self) -> list[SuiteRow]:
        """One suite row per magnitude, named ``<key> <value>``."""
        return [
            SuiteRow(
                f"{self.key} {v:g}", ",".join(filter(None, (f"{self.key}={v:g}", self.extra))), self.gating
            )
            for v in self.values
        ]


SWEEPS: tuple[Sweep, ...] = (
    Sweep("mass_scale", (0.7, 0.8, 0.9, 1.1, 1.2, 1.3), 1.0, "x"),
    Sweep("payload_kg", (0.1, 0.3, 0.5, 0.75), 0.0, "kg at each fingertip", "payload_at=fingertip"),
    Sweep("friction_nm", (0.25, 0.5, 1.0, 1.5), 0.0, "N*m added"),
    Sweep("damping", (0.5, 1.0, 2.0, 3.0), 0.0, "N*m*s/rad added"),
    Sweep("strength", (0.6, 0.7, 0.8, 0.9), 1.0, "x"),
    Sweep("action_delay_ticks", (1, 2, 3), 0.0, "ticks"),
    Sweep("offset_rad", (0.005, 0.01, 0.02), 0.0, "rad", gating="none"),
)
"""The sweeps: each holds the suite's value of its key (mass 0.8 / 1.2, payload 0.5 kg, friction 1.0,
damping 1.0, strength 0.8, delay 2, offset 0.01)."""

PLOTTED: Mapping[str, tuple[str, str | float, str]] = {
    "track": ("fingertip cm", "max_fingertip_error_cm", "mean fingertip error, cm"),
    "reach": ("median end cm", "max_median_end_cm", "median segment-end distance, cm"),
    "piano": ("F1 %", "min_success_pct", "F1 (step mean), %"),
}
"""Per task: the suite table's metric column (``deploy.robustness.task_metrics``), its line (a gate
threshold's name, or a value), the axis label."""


def sweep_rows(keys: Sequence[str] | None = None) -> list[SuiteRow]:
    """The nominal row, then every sweep's rows (``keys``: those sweeps, in ``SWEEPS`` order; None: all).

    Raises ``ValueError`` naming the valid keys for an unknown one.
    """
    known = [s.key for s in SWEEPS]
    unknown = [k for k in keys or () if k not in known]
    if unknown:
        raise ValueError(f"unknown sweep key(s) {unknown}; valid: {known}")
    chosen = [s for s in SWEEPS if keys is None or s.key in keys]
    return [SuiteRow("nominal", ""), *(r for s in chosen for r in s.rows())]


def points(rows: Sequence[Mapping[str, Any]], task: str) -> dict[str, list[tuple[float, float | None, str]]]:
    """Per sweep key: ``(magnitude, metric, verdict)``, the nominal point first at the key's nominal value.

    ``rows``: ``SuiteResult.to_dict()["rows"]`` of a ``sweep_rows`` run (names ``<key> <value>``).
    """
    metric = PLOTTED[task][0]

    def value(row: Mapping[str, Any]) -> float | None:
        return row["metrics"].get(metric)

    by_name = {r["name"]: r for r in rows}
    nominal = by_name.get("nominal")
    out: dict[str, list[tuple[float, float | None, str]]] = {}
    for s in SWEEPS:
        pts = [
            (v, value(by_name[r.name]), by_name[r.name]["verdict"])
            for v, r in zip(s.values, s.rows(), strict=True)
            if r.name in by_name
        ]
        if not pts:
            continue
        if nominal is not None:
            pts.append((s.nominal, value(nominal), nominal["verdict"]))
        out[s.key] = sorted(pts)
    return out


def plot(task: str, policy: str, pts: Mapping[str, list[tuple[float, float | None, str]]], out: Path) -> None:
    """One panel per sweep: metric against magnitude, nominal ringed, the gate's line, misses red crosses."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import bar_policy.tasks.registry  # noqa: F401  (registers every task's gate)

    _, line, label = PLOTTED[task]
    threshold = getattr(gate_for(task), line) if isinstance(line, str) else line
    sweeps = {s.key: s for s in SWEEPS}
    n = len(pts)
    cols = min(n, 4)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.6 * rows), squeeze=False)
    for ax, (key, p) in zip(axes.flat, pts.items(), strict=False):
        s = sweeps[key]
        xs = [x for x, y, _ in p if y is not None]
        ys = [y for _, y, _ in p if y is not None]
        ax.plot(xs, ys, "-", color="0.5", lw=1)
        for x, y, verdict in p:
            if y is None:
                continue
            style = {"MISS": ("x", "tab:red"), "report": ("s", "0.4")}.get(verdict, ("o", "tab:blue"))
            ax.plot([x], [y], style[0], color=style[1], ms=6)
            if x == s.nominal:
                ax.plot([x], [y], "o", mfc="none", mec="k", ms=11)
        if threshold is not None:
            ax.axhline(threshold, color="tab:red", ls="--", lw=1)
        ax.set_xlabel(f"{key} ({s.unit})", fontsize=8)
        ax.set_ylabel(label, fontsize=8)
        ax.tick_params(labelsize=7)
        if s.gating == "none":
            ax.set_title("reported, not gated", fontsize=7)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.suptitle(f"{Path(policy).name} ({task}): sim target, gate line dashed, misses x", fontsize=9)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=90)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--policy", required=True, help="ONNX policy file (its task picks the evaluation)")
    p.add_argument("--out", type=Path, required=True, help="the PNG")
    p.add_argument("--json", type=Path, default=None, help="every point's figures")
    p.add_argument(
        "--keys", default=None, help=f"sweeps, comma-separated (default all: {[s.key for s in SWEEPS]})"
    )
    p.add_argument("--episodes", type=int, default=None, help="reach: episodes per point")
    p.add_argument("--clips", default=None, help="track: clips per point (as bar-deploy eval)")
    p.add_argument("--songs", default=None, help="piano: songs per point (as bar-deploy eval)")
    p.add_argument("--random-songs", type=int, default=None, help="piano: random songs per point")
    a = p.parse_args(argv)

    from bar_policy.deploy.episodes import SimEpisodes
    from bar_policy.deploy.policy import load_policy
    from bar_policy.deploy.robustness import run_suite
    from bar_policy.deploy.tasks import get_task

    rows = sweep_rows(a.keys.split(",") if a.keys else None)
    policy = load_policy(a.policy)
    task = get_task(policy.task)  # type: ignore[attr-defined]
    if task.name not in PLOTTED:
        raise SystemExit(f"no envelope metric for task {task.name!r}; tasks: {sorted(PLOTTED)}")
    eval_options = ("episodes", "clips", "songs", "random_songs")  # unset ones keep the task's defaults
    args = argparse.Namespace(**{k: getattr(a, k) for k in eval_options if getattr(a, k) is not None})
    t0 = time.perf_counter()
    suite = run_suite(
        policy,
        task,
        args,
        lambda pert: SimEpisodes(policy, perturbation=pert),
        rows,
        progress=lambda line: print(f"[{time.perf_counter() - t0:6.0f} s] {line}", flush=True),
    )
    record = suite.to_dict()
    pts = points(record["rows"], task.name)
    plot(task.name, a.policy, pts, a.out)
    if a.json:
        a.json.write_text(json.dumps({"points": pts, **record}, indent=1, default=str))
    print(suite.format())
    print(f"envelope: {a.out} ({len(rows)} points, {time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
