"""detach.train package."""
