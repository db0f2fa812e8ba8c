"""The ``--backend rsl-rl`` trainer: rsl-rl-lib's PPO (torch) on the MJX env.

``entry.run_rsl_rl`` is its entry (torch-free: it compiles the envs' programs, then imports torch's
side); ``backend.train_rsl_rl`` is the loop; ``programs`` is the jax side of its envs, ``env`` the torch
``VecEnv`` over them; ``config`` maps ``TrainConfig`` to rsl-rl's ``train_cfg``; ``policy``, ``prior``,
``sampling`` and ``state`` are the actor's export, action prior, sync-free Gaussian head and checkpoint
contents; ``torch_bridge`` and ``torch_precision`` are torch's side of the device buffers and the update's
matmul precision.
"""
