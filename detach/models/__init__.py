"""detach.models package."""
