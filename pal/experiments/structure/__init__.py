"""Structure-learning experiments: synthetic SCMs, a babbling body, active design."""
