"""The TensorBoard / Weights & Biases tag of every metric the trainers log: one table for both backends.

The names are rsl-rl's and Isaac Lab's (``rsl_rl.utils.logger.Logger``, Isaac Lab's reward manager), so a
run of either backend reads as its users expect. ``metrics.jsonl`` keeps the record's own keys (left
column); TensorBoard gets the tag (right column).

======================== ============================== ==============================================
record key (``train``)   tag                            meaning
======================== ============================== ==============================================
``episode_reward``       ``Train/mean_reward``          return per episode: the window's mean reward per
                                                        env step x the episode length (steps)
``episode_length``       ``Train/mean_episode_length``  control steps of the episodes that ended in the
                                                        window (absent when none ended)
``reward/<term>``        ``Episode_Reward/<term>``      the term's share of ``episode_reward`` (the same
                                                        scaling: the terms sum to it)
``<ratio>``              ``Metrics/<ratio>``            the task's ratios over the window's training
                                                        steps: ``success_rate``, ``final_distance`` (m)
                                                        for reach; ``rollout_sums.RatioWindow``
``loss/value_function``  ``Loss/value_function``        mean squared error of the value targets (not
                                                        weighted; rsl-rl: its clipped form when on)
``loss/surrogate``       ``Loss/surrogate``             PPO's clipped surrogate loss
``loss/entropy``         ``Loss/entropy``               mean entropy of the policy's distribution, nats
``loss/learning_rate``   ``Loss/learning_rate``         Adam's rate at the end of the window
``loss/kl``              ``Loss/kl``                    brax only: KL of the update (rsl-rl's PPO does not
                                                        return it)
``loss/total``           ``Loss/total``                 brax only: the loss minimised
``policy_std``           ``Policy/mean_std``            mean std of the action distribution (brax: of the
                                                        pre-tanh normal), action units
``sps``                  ``Perf/total_fps``             env steps per second over the window
======================== ============================== ==============================================

Evaluations go under ``Eval/<key>`` (``Eval/success_rate``, ``Eval/quality/chatter_max_mrad``, ...), the
final evaluation under ``Final/<key>``; any other record kind ``k`` under ``k.capitalize()/<key>``.
"""

from __future__ import annotations

__all__ = ["TRAIN_TAGS", "brax_losses", "rsl_rl_losses", "tag"]

TRAIN_TAGS: dict[str, str] = {
    "episode_reward": "Train/mean_reward",
    "episode_length": "Train/mean_episode_length",
    "policy_std": "Policy/mean_std",
    "sps": "Perf/total_fps",
}
"""Fixed tags of ``train`` records; the prefixed keys (``reward/``, ``loss/``, ratios) follow ``tag``."""

_PREFIXES = {"reward/": "Episode_Reward/", "loss/": "Loss/"}


def tag(kind: str, key: str) -> str:
    """The tag of record key ``key`` in a record of kind ``kind`` (``train``, ``eval``, ``final``, ...)."""
    if kind != "train":
        return f"{kind.capitalize()}/{key}"
    if key in TRAIN_TAGS:
        return TRAIN_TAGS[key]
    for prefix, tb in _PREFIXES.items():
        if key.startswith(prefix):
            return tb + key[len(prefix) :]
    return f"Metrics/{key}"


def brax_losses(metrics: dict[str, float], entropy_cost: float, vf_coefficient: float) -> dict[str, float]:
    """Brax's loss metrics (``ppo_loss``'s names) as the table's record keys.

    ``v_loss`` is ``0.5 * vf_coefficient * mean(err^2)`` and ``entropy_loss`` is ``-entropy_cost * mean
    entropy``: both are divided back to the unweighted figures rsl-rl logs (left out when their weight is 0).
    """
    out = {"loss/surrogate": metrics["policy_loss"], "loss/total": metrics["total_loss"]}
    if vf_coefficient > 0:
        out["loss/value_function"] = metrics["v_loss"] / (0.5 * vf_coefficient)
    if entropy_cost > 0:
        out["loss/entropy"] = -metrics["entropy_loss"] / entropy_cost
    for src, dst in (("kl", "loss/kl"), ("learning_rate", "loss/learning_rate")):
        if src in metrics:
            out[dst] = metrics[src]
    if "policy_dist_mean_std" in metrics:
        out["policy_std"] = metrics["policy_dist_mean_std"]
    return out


def rsl_rl_losses(losses: dict[str, float], learning_rate: float) -> dict[str, float]:
    """rsl-rl's ``PPO.update`` dict (``value``, ``surrogate``, ``entropy``, ...) as the record's keys."""
    names = {"value": "value_function"}
    out = {f"loss/{names.get(k, k)}": float(v) for k, v in losses.items()}
    out["loss/learning_rate"] = float(learning_rate)
    return out
