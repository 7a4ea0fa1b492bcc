"""The right foot (OpenSim bones, a skin envelope, the soft tissue between them, gmsh)."""
