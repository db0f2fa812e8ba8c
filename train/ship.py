"""Train a policy and publish it (checkpoints/ + docs/), in one shot, if it passes the ship gate.

    python train/ship.py                       # train with the gpu preset (LiteReach), then publish
    python train/ship.py --from-run runs/X     # publish an existing run only
    python train/ship.py --from-run runs/X --iterate auto   # ship policy_best.onnx if it scores higher
    python train/ship.py --from-run runs/T --name lite_track_arms   # a LiteTrack run: the tracker
    python train/ship.py --ppo.num-timesteps 60000000   # any train/ppo.py flag passes through
    python train/ship.py --from-run runs/X --robustness "payload 0.5 kg palm,push 10 N"   # those rows only
    python train/ship.py --from-run runs/X --robustness none   # the nominal gate alone (recorded as such)
    python train/ship.py --rejudge lite_track_arms             # judge a published file again, as deployed now
    python train/ship.py --from-run runs/X --robustness-targets sim   # the tier on the sim target alone

The task comes from the run (``env_name`` in its ``final_eval.json`` / ``config.json``: LiteReach and
LiteReachNeck -> reach, LiteTrack -> track); the default name is ``lite_<task>_<mode>``.

Before anything is written, the ONNX file to ship is evaluated on held-out data on the C MuJoCo sim target
by the evaluation ``bar-deploy eval`` runs (its defaults: reach, 100 seeded episodes; track, the ``heldout``
clip set), and judged by the ship gate (``bar_policy.quality.gate``): the thresholds are printed, then PASS
or one line per miss naming the metric, its value and the threshold. A file that misses is refused: nothing
is written. A file that passes is published: ``checkpoints/<name>.onnx`` and ``checkpoints/<name>.json``
(with the gate's record under ``ship_gate``: task, thresholds, verdict, the report's figures); for reach
also ``docs/training_curve.png`` and the results block of ``docs/reach.md`` (they describe the reach
policy, so a tracker run leaves them alone), then whether the issue's reach targets were met.

The robustness tier (``--robustness ROWS``: ``suite``, the default, for every row of
``robot/perturb_suite.py`` but ``nominal``, or row names, comma-separated) runs after the nominal gate
passed: each row is the same held-out evaluation on the perturbed sim target, then on the emulated bus
whose robot is the perturbed one (``--robustness-targets``, default ``sim,bus``: the real target's CAN code
and the lockstep emulator, ``deploy.episodes.BusEpisodes``; ``deploy.robustness.run_suite``), judged by
the gate as far as the row's ``gating`` says; each table is printed and every row's verdict (PASS, MISS,
``report``), its misses and figures go into the published JSON under ``ship_gate.robustness`` (sim) and
``ship_gate.robustness_bus``. A file that misses a gated row is refused (exit 3, the rows named,
nothing written): a policy that fails on the robots the suite stands for does not ship. ``--robustness
none`` publishes on the nominal gate alone, said on the terminal and recorded
(``ship_gate.robustness.verdict`` ``not run``), for a file meant for the model only.

Exit status:
    0: published (reach: and the final MJX evaluation reached >= 95 % success).
    1: published, but the reach run's final MJX evaluation missed 95 % success.
    2: nothing published: the run or its file could not be evaluated (missing files, no env name, a file
       the deploy loader refuses, a file of another task than the run's).
    3: nothing published: the file misses the ship gate on held-out data, or a gated row of the
       robustness tier (each miss is printed).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from collections.abc import Mapping
from dataclasses import asdict
from pathlib import Path
from typing import Any

from bar_policy.quality.gate import Miss, check, gate_for, thresholds_text
from bar_policy.robot.perturb_suite import SUITE, SuiteRow
from bar_policy.tasks.registry import TASKS
from bar_policy.training.cli import parse_config
from bar_policy.training.publish import ITERATES, choose_iterate, publish

SHIPPED, TARGET_MISSED, NOT_EVALUATED, REFUSED = 0, 1, 2, 3
"""Exit codes (see the module docstring)."""

ENV_TASKS: dict[str, str] = {e.name: r.name for r in TASKS for e in r.envs}
"""A run's env name -> the task of its policies (the env's ``task_name``, the file's ``bar.task``)."""


def run_config(run_dir: str | Path) -> dict[str, Any]:
    """The run's config record: ``train``, ``env`` (``final_eval.json``'s ``config``, else config.json)."""
    run_dir = Path(run_dir)
    for path, key in ((run_dir / "final_eval.json", "config"), (run_dir / "config.json", None)):
        if path.exists():
            data = json.loads(path.read_text())
            record = data.get(key) if key else data
            if isinstance(record, dict) and "train" in record:
                return record
    raise FileNotFoundError(f"{run_dir} has no final_eval.json or config.json with the run's config")


def run_task(run_dir: str | Path) -> tuple[str, str]:
    """``(env name, task)`` of a run, from the env name its config records.

    Raises:
        FileNotFoundError: no config record; ValueError: no env name, or one with no task here.
    """
    env_name = run_config(run_dir)["train"].get("env_name")
    if env_name not in ENV_TASKS:
        known = sorted(ENV_TASKS)
        raise ValueError(f"{run_dir}: env_name {env_name!r} has no ship task; known envs: {known}")
    return env_name, ENV_TASKS[env_name]


def held_out_evaluation(onnx: str | Path, task: str, options: Mapping[str, Any] | None = None) -> Any:
    """``bar-deploy eval``'s evaluation of ``onnx`` (C MuJoCo sim target, held-out data); its ``EvalReport``.

    Args:
        onnx: the policy file.
        task: the run's task; the file must declare it (else ``PolicyLoadError``).
        options: ``bar-deploy eval`` options by argparse dest (``episodes``, ``clips``, ``hold_s``, ...);
            None: the eval's defaults, the gate's held-out data. Tests pass smaller ones.
    """
    from bar_policy.deploy.episodes import SimEpisodes
    from bar_policy.deploy.policy import load_policy
    from bar_policy.deploy.tasks import get_task

    logging.getLogger("bar_policy.deploy.safety").setLevel(logging.WARNING)  # as bar-deploy eval
    policy = load_policy(onnx, task=task)
    return get_task(task).evaluate(policy, argparse.Namespace(**dict(options or {})), SimEpisodes(policy))


def robustness_rows(text: str) -> tuple[SuiteRow, ...]:
    """The suite rows ``--robustness`` names (comma-separated; ``suite``: every row but nominal; ``none``).

    Raises:
        ValueError: an unknown row name (the valid ones listed), or none given.
    """
    if text.strip() == "none":
        return ()
    if text.strip() == "suite":
        return tuple(r for r in SUITE if r.spec)
    by_name = {r.name: r for r in SUITE}
    names = [n.strip() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in by_name]
    if unknown or not names:
        raise ValueError(
            f"--robustness: unknown suite row(s) {unknown or [text]}; valid: 'suite', 'none' or any of "
            f"{list(by_name)}"
        )
    return tuple(by_name[n] for n in names)


ROBUSTNESS_TARGETS = ("sim", "bus")
"""Where the robustness tier runs (``--robustness-targets``), in order: the C MuJoCo sim target, the emulated
bus (keys of ``deploy.episodes.RUNNERS``, imported only when the tier runs)."""


def robustness_targets(text: str) -> tuple[str, ...]:
    """The targets ``--robustness-targets`` names: comma-separated, each of ``ROBUSTNESS_TARGETS`` once.

    Raises ``ValueError`` naming the valid ones otherwise.
    """
    names = tuple(t.strip() for t in text.split(",") if t.strip())
    bad = [t for t in names if t not in ROBUSTNESS_TARGETS]
    if bad or not names or len(set(names)) != len(names):
        raise ValueError(
            f"--robustness-targets {text!r}: give each of {', '.join(ROBUSTNESS_TARGETS)} at most once, "
            "comma-separated"
        )
    return names


def robustness_tier(
    onnx: str | Path,
    task: str,
    rows: tuple[SuiteRow, ...],
    options: Mapping[str, Any] | None = None,
    target: str = "sim",
) -> Any:
    """Each row's held-out evaluation on the perturbed ``target``, judged (``deploy.robustness.SuiteResult``).

    ``options``: as ``held_out_evaluation``'s (None: the eval's defaults). ``target``: ``sim`` (the C MuJoCo
    sim target) or ``bus`` (the emulated bus, ``BusEpisodes``).
    """
    from bar_policy.deploy.episodes import RUNNERS
    from bar_policy.deploy.policy import load_policy
    from bar_policy.deploy.robustness import run_suite
    from bar_policy.deploy.tasks import get_task

    policy = load_policy(onnx, task=task)
    args = argparse.Namespace(**dict(options or {}))
    return run_suite(
        policy,
        get_task(task),
        args,
        lambda p: RUNNERS[target](policy, perturbation=p),
        rows,
        progress=lambda line: print(line, flush=True),
    )


def robustness_record(suite: Any) -> dict[str, Any]:
    """``ship_gate.robustness``: each row's name, spec, gating, verdict, misses and figures; the verdict.

    ``suite`` None: the tier was not run (``--robustness none``).
    """
    if suite is None:
        return {"verdict": "not run", "rows": []}
    rows = []
    for r in suite.rows:
        d = r.to_dict()
        d.pop("gate_report", None)
        d["report"] = {k: v for k, v in r.report.items() if k != "episodes"}
        rows.append(d)
    return {"verdict": "pass" if suite.passed else "miss", "target": suite.target, "rows": rows}


def gate_record(task: str, report: Mapping[str, Any], misses: list[Miss]) -> dict[str, Any]:
    """The gate's record for the published JSON: task, thresholds, verdict, misses, the report's figures."""
    return {
        "task": task,
        "thresholds": {k: v for k, v in asdict(gate_for(task)).items() if v is not None and v != ()},
        "verdict": "pass" if not misses else "miss",
        "misses": [m.text for m in misses],
        "report": {k: v for k, v in report.items() if k != "episodes"},  # the summary judges chatter too
        "episodes": len(report.get("episodes") or []),
    }


def _eval_lines(result: Any) -> list[str]:
    """The evaluation's summary without its own gate lines (ship prints the gate's verdict itself)."""
    lines = result.format().splitlines()
    gate = result.gate_lines()
    return lines[: -len(gate)] if lines[-len(gate) :] == gate else lines


def judge(
    onnx: str | Path,
    task: str,
    result: Any,
    rows: tuple[SuiteRow, ...],
    eval_options: Mapping[str, Any] | None,
    checkpoints_dir: str,
    targets: tuple[str, ...] = ROBUSTNESS_TARGETS,
) -> dict[str, Any] | None:
    """Both gates on ``onnx``, its held-out ``result`` given, printed.

    Returns the ``ship_gate`` record, or None when the file is refused (a nominal miss, or a miss on a gated
    row of ``rows`` on one of ``targets``, which run in order and stop at the first that misses).
    """
    report = result.gate_report()
    misses = check(task, report)
    print("\n".join(_eval_lines(result)))
    print(thresholds_text(task))
    for line in ["gate: PASS"] if not misses else [f"gate: MISS {m}" for m in misses]:
        print(line)
    if misses:
        print(
            f"ship: refused: {onnx} misses the {task} ship gate on held-out data ({len(misses)} miss(es)); "
            f"nothing written to {checkpoints_dir}/"
        )
        return None
    ship_gate = gate_record(task, report, misses)
    if not rows:
        print("robustness tier: not run (--robustness none): published on the nominal gate alone")
        ship_gate["robustness"] = robustness_record(None)
        return ship_gate
    for target in targets:
        where = "the emulated bus" if target == "bus" else "a perturbed sim target"
        print(f"robustness tier: {len(rows)} row(s), each the held-out evaluation on {where}")
        suite = robustness_tier(onnx, task, rows, eval_options, target)
        print(suite.format())
        ship_gate["robustness" if target == "sim" else f"robustness_{target}"] = robustness_record(suite)
        if not suite.passed:
            missed = [r.row.name for r in suite.rows if r.verdict == "MISS"]
            print(
                f"ship: refused: {onnx} misses the robustness tier on {len(missed)} row(s): "
                f"{', '.join(missed)} ({suite.target}); nothing written to {checkpoints_dir}/"
            )
            return None
    return ship_gate


def rejudge(
    name: str,
    checkpoints_dir: str,
    rows: tuple[SuiteRow, ...],
    eval_options: Mapping[str, Any] | None,
    targets: tuple[str, ...] = ROBUSTNESS_TARGETS,
) -> int:
    """``--rejudge NAME``: both gates on the published ``checkpoints/NAME.onnx`` as the deploy side runs it.

    On a pass its JSON's ``ship_gate`` is replaced (the rest kept, ``rejudged`` stamped), on a miss nothing
    is written (exit 3). Why: a change on the deploy side (a runtime default, the suite) changes what a
    shipped file does on the robot, and its record must say what it does now.
    """
    path = Path(checkpoints_dir) / f"{name}.json"
    onnx = path.with_suffix(".onnx")
    try:
        record = json.loads(path.read_text())
        task = record["ship_gate"]["task"]
        result = held_out_evaluation(onnx, task, eval_options)
    except (FileNotFoundError, KeyError, ValueError) as e:
        print(f"ship: error: --rejudge {name}: {type(e).__name__}: {e}", file=sys.stderr)
        return NOT_EVALUATED
    print(f"held-out evaluation of {onnx} (published, task {task}), re-judged:")
    ship_gate = judge(onnx, task, result, rows, eval_options, checkpoints_dir, targets)
    if ship_gate is None:
        return REFUSED
    from bar_policy.provenance import collect

    ship_gate["rejudged"] = collect()
    record["ship_gate"] = ship_gate
    path.write_text(json.dumps(record, indent=2, sort_keys=True))
    print(f"re-judged: {path} (ship_gate replaced)")
    return SHIPPED


def main(argv: list[str] | None = None, *, eval_options: Mapping[str, Any] | None = None) -> int:
    """Train (unless ``--from-run``), judge the file by the ship gate, publish; the exit status.

    ``eval_options``: for tests only, smaller held-out evaluations (see ``held_out_evaluation``).
    """
    pre = argparse.ArgumentParser(
        prog="python train/ship.py",
        description="Train a policy (or take a finished run) and publish it under checkpoints/ if it passes "
        "the ship gate: the nominal held-out evaluation, then the robustness suite on the sim target and "
        "the emulated bus.",
        add_help=False,
    )
    pre.add_argument("--from-run", default=None, help="publish this finished run instead of training")
    pre.add_argument("--name", default=None, help="file stem under checkpoints/ (default lite_<task>_<mode>)")
    pre.add_argument(
        "--iterate",
        default="last",
        choices=ITERATES,
        help="ship the last iterate, the best evaluated one, or the one with the higher final evaluation",
    )
    pre.add_argument(
        "--raw-throughput",
        type=int,
        default=None,
        help="after training, time the batched env alone at this batch size (0 = skip); recorded in the JSON "
        "(default: 4096 after training here, 0 with --from-run: the machine that trained is not this one)",
    )
    pre.add_argument(
        "--robustness",
        default="suite",
        metavar="ROWS",
        help="after the nominal gate, run these robustness-suite rows and refuse (exit 3) a file that misses "
        "a gated one: 'suite' (every row but nominal; the default), row names from robot/perturb_suite.py "
        "(comma-separated), or 'none' (the nominal gate alone, recorded as not run)",
    )
    pre.add_argument(
        "--robustness-targets",
        default=",".join(ROBUSTNESS_TARGETS),
        metavar="TARGETS",
        help="where the robustness tier runs, comma-separated, a file must pass on each: sim (the C MuJoCo "
        "sim target), bus (the real target's CAN code and the lockstep emulator); default sim,bus",
    )
    pre.add_argument(
        "--rejudge",
        default=None,
        metavar="NAME",
        help="judge the published checkpoints/NAME.onnx again (both gates, as the deploy side runs it now) "
        "and replace its JSON's ship_gate on a pass; nothing else runs",
    )
    pre.add_argument("--checkpoints-dir", default="checkpoints", help="where the ONNX and JSON go")
    pre.add_argument("--docs-dir", default="docs", help="where the reach curve and reach.md results go")
    argv = sys.argv[1:] if argv is None else list(argv)
    if "-h" in argv or "--help" in argv:  # ship's own options; the rest pass through to training
        pre.print_help()
        print("\nany other flag is a training flag (without --from-run): python train/ppo.py --help")
        return SHIPPED
    known, rest = pre.parse_known_args(argv)
    try:
        rows = robustness_rows(known.robustness)
        targets = robustness_targets(known.robustness_targets)
    except ValueError as e:
        print(f"ship: error: {e}", file=sys.stderr)
        return NOT_EVALUATED
    if known.rejudge is not None:
        if known.from_run is not None or rest:
            print(
                "ship: error: --rejudge judges a published file; it takes no run or training options",
                file=sys.stderr,
            )
            return NOT_EVALUATED
        return rejudge(known.rejudge, known.checkpoints_dir, rows, eval_options, targets)
    if known.from_run is not None and rest:
        print(
            f"ship: error: --from-run publishes an existing run; {rest} are not ship options and would "
            "only apply to a training run (ship options: see --help)",
            file=sys.stderr,
        )
        return NOT_EVALUATED
    if known.from_run is None:
        if not any(a.startswith("--run-name") for a in rest):
            rest = [*rest, "--run-name", f"ship-{time.strftime('%Y%m%d-%H%M%S')}"]
        cfg = parse_config(rest)
        from bar_policy.training.run import run

        run_dir = run(cfg).run_dir
    else:
        run_dir = known.from_run

    try:
        env_name, task = run_task(run_dir)
        onnx, _ = choose_iterate(run_dir, known.iterate)
        result = held_out_evaluation(onnx, task, eval_options)
    except (FileNotFoundError, ValueError) as e:  # ValueError: PolicyLoadError, OptionError, bad records
        print(f"ship: error: {e}", file=sys.stderr)
        print("ship: nothing published")
        return NOT_EVALUATED
    print(f"held-out evaluation of {onnx} ({env_name} run {run_dir}, task {task}):")
    ship_gate = judge(onnx, task, result, rows, eval_options, known.checkpoints_dir, targets)
    if ship_gate is None:
        return REFUSED

    mode = run_config(run_dir).get("env", {}).get("mode", "arms")
    name = known.name or f"lite_{task}_{mode}"
    paths = publish(
        run_dir,
        name=name,
        iterate=known.iterate,
        checkpoints_dir=known.checkpoints_dir,
        docs_dir=known.docs_dir if task == "reach" else None,
        extra={"ship_gate": ship_gate},
    )
    final = json.loads(paths["json"].read_text())
    if known.raw_throughput is None:
        known.raw_throughput = 0 if known.from_run is not None else 4096
    if known.raw_throughput:
        from bar_policy import envs
        from bar_policy.training.throughput import raw_env_steps_per_second

        env, randomizer = envs.load_for_training(env_name)
        raw = raw_env_steps_per_second(
            env, envs.wrap_for_brax_training, num_envs=known.raw_throughput, randomizer=randomizer
        )
        final["raw_env_throughput"] = raw
        paths["json"].write_text(json.dumps(final, indent=2, sort_keys=True))
        print(
            f"raw env throughput: {raw['env_steps_per_s']:,.0f} env steps/s at {raw['num_envs']} envs; "
            f"training end to end: {final['train_sps_end_to_end']:,.0f} env steps/s"
        )
    print(f"published: {', '.join(str(p) for p in paths.values())}")
    if task != "reach":
        return SHIPPED
    success = final["final_eval"]["success_rate"]
    ttt = final.get("time_to_threshold_s")
    ok_success = success >= 0.95
    ok_time = ttt is not None and ttt <= 300
    print(f"target >= 95% final success: {'MET' if ok_success else 'NOT MET'} ({100 * success:.2f}%)")
    print(f"target <= 5 min to 95% eval success: {'MET' if ok_time else 'NOT MET'} ({ttt} s)")
    return SHIPPED if ok_success else TARGET_MISSED


if __name__ == "__main__":
    sys.exit(main())
