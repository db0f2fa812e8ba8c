"""The observation contract shared by training and deployment.

``from bar_policy.obs import ObservationManager`` is the schema import; ``python -m bar_policy.obs`` prints
each shipped layout's fingerprint.
"""

from bar_policy.obs.manager import (
    SHIPPED_LAYOUTS,
    ObservationManager,
    ObservationSchema,
    ObsTerm,
    shipped_managers,
)
from bar_policy.obs.terms import TERM_CATALOG

__all__ = [
    "SHIPPED_LAYOUTS",
    "TERM_CATALOG",
    "ObsTerm",
    "ObservationManager",
    "ObservationSchema",
    "shipped_managers",
]
