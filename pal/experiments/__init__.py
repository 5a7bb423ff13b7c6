"""Scripted experiments and benchmarks, one module each, in one protocol.

Every module registers its entry with :func:`pal.experiments.registry.register`: a frozen
``Config`` (nested sub-configs, a ``seed``), a quick and a tiny config, and
``run(config, progress_bar=False) -> Report`` (:mod:`pal.experiments.report`). The ``pal``
command finds entries through :func:`pal.experiments.registry.entries`, builds configs with
:func:`pal.experiments.runner.configure` (``--set a.b=VALUE``), runs them with
:func:`pal.experiments.runner.execute`, and :mod:`pal.experiments.render` writes every
report as markdown, JSON and PNG.
"""
