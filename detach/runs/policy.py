"""A run's trained actor, rebuilt for an env: what evaluation, export and play all start from."""

from __future__ import annotations

from detach.train.trained_actor import load_trained_actor as load_policy

__all__ = ["load_policy"]
