"""detach.envs package."""
