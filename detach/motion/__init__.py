"""detach.motion package."""
