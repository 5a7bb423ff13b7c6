"""The experiment protocol: registry, configs, reports, renderers, runner, sweeps and engines.

Every module under :mod:`pal.experiments` registers its entry with
:func:`pal.lab.registry.register`: a frozen ``Config`` (nested sub-configs, a ``seed``), a quick
and a tiny config, and ``run(config, progress_bar=False) -> Report`` (:mod:`pal.lab.report`).
The ``pal`` command finds entries through :func:`pal.lab.registry.entries`, builds configs with
:func:`pal.lab.runner.configure` (``--set a.b=VALUE``), runs them with
:func:`pal.lab.runner.execute`, and :mod:`pal.lab.render` writes every report as markdown, JSON
and PNG. :mod:`pal.lab.sweep` runs one entry over a grid × seeds, locally or on Ray
(:mod:`pal.lab.ray_engine`, the only module that imports Ray).
"""
