"""The scene: every component of a model and the one step that advances them."""

from artifem.scene.scene import Scene

__all__ = ["Scene"]
