"""The piano's key-pose prior alone (a zero MLP) as an ONNX policy file, and its F1 on the held-out songs.

    python bench/piano_prior.py --out prior.onnx                       # write the file (CPU, ~1 min)
    bar-deploy eval --policy prior.onnx                                # F1 per held-out song, sim target
    python bench/piano_prior.py --out prior.onnx --eval sim bus        # ... here, and through the bus
    python bench/piano_prior.py --out v.onnx --prior hover_m=0.02 decay=0.7 --eval sim   # a variant

The file is the policy ``bar-train --env LitePiano --preset piano`` would export before its first update,
with the MLP's output at exactly zero (training starts it at ``PRIOR_INIT_SCALE`` = 0.01 of brax's init):
``actions = tanh(0 + atanh(prior(obs))) = prior(obs)``, the prior written into the graph
(``obs.action_prior.BlendPrior``), the env's metadata (``training.metadata.policy_metadata`` of
``LitePiano``: action scale, 3 Hz filter, observation schema), the export's parity gate against the
prior's numpy ``apply``. ``--prior FIELD=VALUE`` changes ``KeyPosePriorConfig`` fields (the per-frame
ones as comma-separated lists: ``frame_weights=1,.6,...``, 11 values), ``--lead`` the pressing frames
(the preset's 2), ``--filter-hz`` the action filter written into the metadata, ``--gains`` the gain
profile (``robot.gains``).

``--eval sim bus`` plays the songs (``--songs``, default the held-out ones) through ``bar-deploy eval``'s
code (``tasks.piano.evaluate``: the deploy runtime, the safety supervisor): ``sim`` on the C MuJoCo sim
target, ``bus`` through ``RealTarget`` and the lockstep Robstride emulator on virtual CAN buses
(``EmulatedBusTarget`` in the keyboard's scene: the 16-bit feedback codec, the firmware's MIT law).
``--count-in S`` plays them with that count-in (``bank.PlaybackConfig``; default its own); the song lead
is the file's (``source.policy_playback``). It prints one
markdown row per song and column (F1, precision, recall, pooled F1, faulted) and writes ``--json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from bar_policy.deploy.episodes import SimEpisodes
from bar_policy.deploy.policy import load_policy
from bar_policy.robot.gains import GAINS
from bar_policy.tasks.piano.bank import PlaybackConfig
from bar_policy.tasks.piano.evaluate import evaluate
from bar_policy.tasks.piano.keyboard import compact_config
from bar_policy.tasks.piano.prior import KeyPosePriorConfig
from bar_policy.tasks.piano.results import PianoEval
from bar_policy.tasks.piano.scene import keyboard_scene
from bar_policy.tasks.piano.song_library import HELDOUT, library_song
from bar_policy.tasks.piano.source import policy_playback


def _prior_config(items: list[str]) -> KeyPosePriorConfig:
    """``FIELD=VALUE`` pairs on ``KeyPosePriorConfig()`` (numbers; ``frame_weights=W0,W1,...``)."""
    fields = {f.name for f in dataclasses.fields(KeyPosePriorConfig)}
    changes = {}
    for item in items:
        name, _, value = item.partition("=")
        if name not in fields or not value:
            raise SystemExit(f"--prior {item!r}: need FIELD=VALUE with FIELD one of {sorted(fields)}")
        if name in ("frame_weights", "edge_weights"):
            changes[name] = tuple(float(v) for v in value.split(","))
        elif getattr(KeyPosePriorConfig(), name) is None:
            changes[name] = float(value)
        else:
            changes[name] = type(getattr(KeyPosePriorConfig(), name))(float(value))
    return KeyPosePriorConfig(**changes)


def write_prior_policy(
    path: Path, prior_config: KeyPosePriorConfig, lead: int, filter_hz: float | None, gains: str = "robot"
) -> dict:
    """Export the zero-MLP policy of the env's prior to ``path`` (``export_policy``'s summary), on the gain
    profile ``gains`` (``robot.gains``: the file records it, its key poses hold with its Kp)."""
    from bar_policy.export.graph import MlpPolicy
    from bar_policy.export.policy import export_policy
    from bar_policy.tasks.piano.env import LitePiano, default_config
    from bar_policy.training.metadata import policy_metadata

    cfg = dataclasses.replace(default_config(), prior=prior_config, gains=gains)
    if filter_hz is not None:
        cfg = dataclasses.replace(cfg, action_filter_hz=filter_hz)
    env = LitePiano(cfg)
    prior = env.action_prior(lead)
    policy = MlpPolicy.prior_only(env.obs_manager.size, prior)
    record = {
        "backend": "none: the key-pose prior alone (bench/piano_prior.py)",
        "prior": dataclasses.asdict(prior_config),
        "prior_lead_steps": lead,
        "gains": gains,
    }
    meta = policy_metadata(env, training=record)
    return export_policy(policy, meta, path, prior.apply)


def run_column(name: str, policy_path: Path, songs: list[str], count_in_s: float | None) -> PianoEval:
    """The songs on the sim target (``sim``) or through the emulated bus (``bus``).

    Played as the file trained (``source.policy_playback``: its song lead), with ``count_in_s`` when given.
    """
    policy = load_policy(str(policy_path))
    playback = policy_playback(policy)
    if count_in_s is not None:
        playback = dataclasses.replace(playback, count_in_s=count_in_s)
    runner = SimEpisodes(policy)
    tracks = [library_song(s) for s in songs]
    if name == "sim":
        return evaluate(policy, tracks, runner=runner, playback=playback)
    from bar_policy.deploy.targets.emulated import EmulatedBusTarget

    target = EmulatedBusTarget(policy.robot.mode, policy.policy_dt, scene=keyboard_scene(compact_config()))
    try:
        return evaluate(policy, tracks, target, runner=runner, playback=playback)
    finally:
        target.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True, help="the policy file to write (or read: --no-write)")
    p.add_argument("--no-write", action="store_true", help="evaluate an existing --out file")
    p.add_argument("--prior", nargs="*", default=[], metavar="FIELD=VALUE")
    p.add_argument("--lead", type=int, default=2, help="goal-key frames 0..LEAD press (the preset's 2)")
    p.add_argument("--filter-hz", type=float, help="action filter cutoff, Hz (default the env's 3)")
    p.add_argument("--eval", nargs="*", default=[], choices=("sim", "bus"))
    p.add_argument("--songs", default=",".join(HELDOUT), help="comma-separated library songs")
    p.add_argument("--count-in", type=float, help="count-in, s (default PlaybackConfig's)")
    p.add_argument("--json", type=Path, help="write the results here")
    p.add_argument(
        "--gains", default="robot", choices=GAINS, help="gain profile (robot.gains; default: robot)"
    )
    args = p.parse_args()
    if not args.no_write:
        t0 = time.perf_counter()
        prior = _prior_config(args.prior)
        summary = write_prior_policy(args.out, prior, args.lead, args.filter_hz, args.gains)
        print(f"wrote {args.out} ({time.perf_counter() - t0:.0f} s, parity {summary['max_abs_error']:.1e})")
    count_in = PlaybackConfig().count_in_s if args.count_in is None else args.count_in
    songs = args.songs.split(",")
    out = {
        "policy": str(args.out),
        "prior": args.prior,
        "lead": args.lead,
        "filter_hz": args.filter_hz,
        "gains": args.gains,
        "count_in_s": count_in,
        "columns": {},
    }
    if args.eval:
        print(f"count-in {count_in} s, prior {args.prior or 'default'}, lead {args.lead}")
        print("| column | song | F1 | precision | recall | pooled F1 | faulted |")
        print("|---|---|---:|---:|---:|---:|---|")
    for column in args.eval:
        t0 = time.perf_counter()
        res = run_column(column, args.out, songs, args.count_in)
        for s in res.songs:
            print(
                f"| {column} | {s.song} | {s.f1:.3f} | {s.precision:.3f} | {s.recall:.3f} | "
                f"{s.f1_pooled:.3f} | {'yes, ' + s.end_reason if s.faulted else 'no'} |"
            )
        mean = float(np.mean([s.f1 for s in res.songs]))
        print(f"| {column} | mean over songs ({time.perf_counter() - t0:.0f} s) | {mean:.3f} | | | | |")
        out["columns"][column] = res.to_dict()
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
