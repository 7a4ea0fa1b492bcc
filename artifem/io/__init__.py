"""Mesh readers, mesh checks and result writers."""
