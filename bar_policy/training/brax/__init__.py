"""The default trainer (``--backend brax``): brax's PPO on the MJX env, JAX end to end, data-parallel.

``ppo.train_brax`` is the loop (rollout, update, evaluate, checkpoint); ``programs`` builds its jitted
data-parallel programs and ``state`` runs them on the state a run carries between epochs; ``learner`` is
brax's PPO as per-device functions, over ``networks`` (brax's policy and value MLPs with an action prior) and
``ppo_loss``; ``evaluation`` is the evaluation program's episodes; ``result`` is what a run returns and
exports; ``ignored_settings`` names the ``rsl_rl.*`` settings a brax run leaves unused.
"""
