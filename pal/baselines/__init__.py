"""Reference controllers and peer adapters that the experiments compare pal against.

- :mod:`pal.baselines.pets`: a PETS-style probabilistic ensemble over the full observation,
  planned with CEM (plain torch).
- :mod:`pal.baselines.scripted_pusher`: a pushing controller that reads the ground truth.
- :mod:`pal.baselines.scripted_pusher_v5`: a scripted pusher on Gymnasium's Pusher-v5 that reads
  the true state (the contact episodes of the LoT experiment's Pusher-v5 data).
- :mod:`pal.baselines.counterfactual_peers`: ChiRho and DoWhy-GCM on pal's SCMs (``.[bench]``).
- :mod:`pal.baselines.discovery_peers`: causal-learn's GRaSP and PC (``.[bench]``).
"""
