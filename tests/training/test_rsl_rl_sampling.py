"""rsl-rl's Gaussian head without its host sync (``rsl_rl.sampling.GaussianNoSync``).

The reference is rsl-rl's own ``GaussianDistribution`` (``torch.distributions.Normal(mean, std).sample()``,
i.e. ``torch.normal``): the replacement must draw the same actions from the same generator state, and be
rsl-rl's head in everything else (parameters, log-probabilities, entropy, checkpoints).
"""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")
from rsl_rl.models import MLPModel  # noqa: E402
from rsl_rl.modules import GaussianDistribution  # noqa: E402
from rsl_rl.utils import resolve_callable  # noqa: E402
from tensordict import TensorDict  # noqa: E402

from bar_policy.training.rsl_rl.sampling import GaussianNoSync  # noqa: E402


@pytest.mark.parametrize("std_type", ["scalar", "log"])
def test_samples_equal_rsl_rls_bit_for_bit_from_the_same_seed(std_type):
    # torch.normal(mean, std) fills N(0, 1) and scales: the same draw, so equal floats, not just close ones.
    ref = GaussianDistribution(14, init_std=0.3, std_type=std_type)
    ours = GaussianNoSync(14, init_std=0.3, std_type=std_type)
    with torch.no_grad():
        next(ours.parameters()).copy_(
            torch.linspace(-1.5, -0.5, 14) if std_type == "log" else torch.linspace(0.05, 0.9, 14)
        )
    ref.load_state_dict(ours.state_dict())  # the same keys: a checkpoint of one loads into the other
    mean = torch.randn(256, 14, generator=torch.Generator().manual_seed(1)) * 2.0
    ref.update(mean)
    ours.update(mean)
    torch.manual_seed(7)
    a = ref.sample()
    torch.manual_seed(7)
    b = ours.sample()
    assert b.shape == (256, 14)
    assert torch.equal(a, b)
    # ... and the rest of the head is rsl-rl's own on those actions.
    assert torch.equal(ref.log_prob(a), ours.log_prob(b))
    assert torch.equal(ref.entropy, ours.entropy)


def test_sample_moments_are_the_heads_mean_and_std():
    # Independently of rsl-rl: 200k draws of one row; the sample mean is within 5 standard errors
    # (std / sqrt(n) = 0.3 / 447 = 6.7e-4 -> 3.4e-3) and the sample std within 5 of its error
    # (std / sqrt(2 n) = 4.7e-4 -> 2.4e-3).
    ours = GaussianNoSync(3, init_std=0.3)
    ours.update(torch.tensor([[0.5, -1.0, 2.0]]).expand(200_000, 3))
    torch.manual_seed(0)
    x = ours.sample()
    assert torch.allclose(x.mean(0), torch.tensor([0.5, -1.0, 2.0]), atol=3.4e-3)
    assert torch.allclose(x.std(0), torch.full((3,), 0.3), atol=2.4e-3)


def test_sample_before_update_is_a_clear_error():
    with pytest.raises(RuntimeError, match="before update"):
        GaussianNoSync(4).sample()


def test_the_backends_actor_config_builds_this_head():
    from bar_policy.training.config import TrainConfig
    from bar_policy.training.rsl_rl.config import rsl_rl_train_cfg

    dist_cfg = rsl_rl_train_cfg(TrainConfig())["actor"]["distribution_cfg"]
    assert resolve_callable(dist_cfg["class_name"]) is GaussianNoSync
    obs = TensorDict({"policy": torch.zeros(2, 6)}, batch_size=[2])
    actor = MLPModel(obs, {"actor": ["policy"]}, "actor", 4, hidden_dims=[8], distribution_cfg=dist_cfg)
    assert type(actor.distribution) is GaussianNoSync
    assert actor(obs, stochastic_output=True).shape == (2, 4)
