"""The registered experiments and benchmarks, grouped by subject.

- :mod:`~pal.experiments.world_model`: the thesis's B1-B3, online exploration, the spring and
  the analytic queries.
- :mod:`~pal.experiments.perception`: A1-A3 and the real RGB-D frames.
- :mod:`~pal.experiments.closed_loop`: the loop, C1-C4, Pusher-v5 and the hierarchy comparison.
- :mod:`~pal.experiments.structure`: structure learning and active design.
- :mod:`~pal.experiments.language`: grounded queries (LoT).
- :mod:`~pal.experiments.bench`: ``pal bench NAME``.

Every module here is scanned by :func:`pal.lab.registry.entries`; one that defines
``run`` decorated with :func:`pal.lab.registry.register` is an entry. The protocol itself lives
in :mod:`pal.lab`.
"""
