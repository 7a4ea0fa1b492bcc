"""The scene: every component of a model and the one step that advances them."""

from artifem.scene.run import Run, simulate
from artifem.scene.scene import INTEGRATORS, Scene

__all__ = ["INTEGRATORS", "Run", "Scene", "simulate"]
