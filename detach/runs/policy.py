"""A run's trained actor, rebuilt for an env: what evaluation, export and play all start from.

The function lives in `detach.train.trained_actor`, below training, because a teacher
(`train.teachers`) is loaded the same way; this name stays for the runs layer and scripts."""

from __future__ import annotations

from detach.train.trained_actor import load_trained_actor as load_policy

__all__ = ["load_policy"]
