"""The default trainer (``--backend brax``): brax's PPO on the MJX env, JAX end to end, data-parallel.

``ppo.train_brax`` is the loop (rollout, update, evaluate, checkpoint); ``programs`` builds its jitted
data-parallel programs; ``learner`` is brax's PPO as per-device functions, over ``networks`` (brax's policy
and value MLPs with an action prior) and ``ppo_loss``; ``result`` is what a run returns and exports;
``ignored_settings`` names the ``rsl_rl.*`` settings a brax run leaves unused.
"""
