"""Closed-loop experiments: the loop, C1-C4 in the pushing world, Pusher-v5, the hierarchy comparison."""
