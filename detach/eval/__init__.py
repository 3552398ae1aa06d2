"""detach.eval package."""
