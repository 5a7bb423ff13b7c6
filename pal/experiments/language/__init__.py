"""Grounded query experiments (thesis Eq. 6.10): the world model against the simulator."""
