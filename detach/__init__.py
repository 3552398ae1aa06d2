"""detach: long-horizon human-scene interaction experiments on MuJoCo."""

__version__ = "0.1.0"
