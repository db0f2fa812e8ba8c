"""Robot side: policy metadata, ONNX runtime, targets (sim, mock, real). Never imports jax or torch."""

from bar_policy.deploy.metadata import PolicyMetadata

__all__ = ["PolicyMetadata"]
