"""pal: the perception-action loop around a causal world model.

Subpackages: ``pal.experiments`` (scripted experiments and benchmarks) and the ``pal``
command (:mod:`pal.cli`). The world model lives in :mod:`models`, the algorithms in
:mod:`inference`.
"""

__version__ = "0.1.0"
