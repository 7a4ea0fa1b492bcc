"""Jaw and tongue: the level-0 tongue hanging from a rigid, hinged, muscle-driven jaw, full
or with a reduced tongue."""
