"""A grounded query language over the world model (thesis §6.4.3, Eq. 6.8-6.11)."""
