"""detach.runs package."""
