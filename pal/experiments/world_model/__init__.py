"""World-model experiments: B1-B3 (thesis §5.2), online exploration, the spring, analytic queries."""
