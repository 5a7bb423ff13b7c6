"""Perception experiments: A1-A3 (thesis §5.1) on the simulated tabletop, and the real RGB-D frames."""
