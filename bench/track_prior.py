"""The tracker's reference prior alone (a zero MLP) as an ONNX policy file: what training starts from.

    python bench/track_prior.py --out prior.onnx                      # the reference prior (layout v1)
    python bench/track_prior.py --out integral.onnx --error-gain 1    # with the integral term (layout v2)
    bar-deploy eval --policy integral.onnx --perturb suite            # the robustness suite, sim target

The file is the policy ``bar-train --env LiteTrack --network.action-prior reference`` would export before its
first update with the MLP's output at exactly zero: ``actions = tanh(0 + atanh(prior(obs))) = prior(obs)``,
the prior written into the graph (``obs.action_prior.ActionPrior``), the env's metadata
(``training.metadata.policy_metadata`` of ``LiteTrack``: action scale, action filter, observation schema),
the export's parity gate against the prior's numpy ``apply``. ``--lead`` is the reference frame it
commands (``network.prior_lead_steps``, 5 = 100 ms); ``--error-gain G`` > 0 adds the integral term
(``network.prior_error_gain``: the command adds ``G`` times ``joint_error_ema``) and turns the layout's error
average on (``RobotEnvConfig.joint_error_ema``, the track layout's v2). The suite table of a file shows what
the prior alone gives on each perturbed robot, before any learning (docs/robust_training.md, "The integral
prior").
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path


def write_prior_policy(path: Path, lead: int, error_gain: float) -> dict:
    """Write the zero-MLP policy of ``LiteTrack``'s reference prior to ``path``; the export's summary."""
    from bar_policy.export.graph import MlpPolicy
    from bar_policy.export.policy import export_policy
    from bar_policy.tasks.track.config import default_config
    from bar_policy.tasks.track.env import LiteTrack
    from bar_policy.training.metadata import policy_metadata

    cfg = default_config()
    if error_gain > 0:
        cfg = dataclasses.replace(cfg, joint_error_ema=True)
    env = LiteTrack(cfg)
    prior = env.action_prior(lead, error_gain)
    policy = MlpPolicy.prior_only(env.obs_manager.size, prior)
    record = {
        "backend": "none: the reference prior alone (bench/track_prior.py)",
        "prior_lead_steps": lead,
        "prior_error_gain": error_gain,
    }
    return export_policy(policy, policy_metadata(env, training=record), path, prior.apply)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True, help="the policy file to write")
    p.add_argument("--lead", type=int, default=5, help="reference frame, control steps ahead (default 5)")
    p.add_argument(
        "--error-gain", type=float, default=0.0, help="integral term's gain, rad per rad (default 0: none)"
    )
    args = p.parse_args()
    t0 = time.perf_counter()
    summary = write_prior_policy(args.out, args.lead, args.error_gain)
    print(f"wrote {args.out} ({time.perf_counter() - t0:.0f} s, parity {summary['max_abs_error']:.1e})")


if __name__ == "__main__":
    main()
