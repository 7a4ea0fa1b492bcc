"""Anatomical and test models built from artifem."""
