"""bar_policy: a JAX-vectorised learned-policy runtime for the Lite humanoid, with an MJX training env."""

__version__ = "0.1.0"

__all__ = ["__version__"]
