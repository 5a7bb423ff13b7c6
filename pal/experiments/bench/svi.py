"""``pal bench svi``: :func:`inference.infer_state` against hand-written Pyro SVI.

The model is the linear-Gaussian chain A -> B -> C -> D with B latent,

    A ~ N(0, 1),  B = 0.8 A + U_B,  C = -1.2 B + 0.5 U_C,  D = 0.5 C + 0.5 U_D,

over ``units`` units with A, C, D observed. The baseline is the same model written as a
plain Pyro program with the same guide (``AutoNormal``, the same ``init_scale``), the same
optimiser (``ClippedAdam`` with infer_state's lr decay), the same ``Trace_ELBO``
(``num_particles``, vectorised, ``max_plate_nesting=1``), the same number of steps and the
same seed. Both run a setup that pal does not warn about: every ``infer_state`` call of the
run is watched for :class:`inference.PoorPosteriorWarning`, and the target is "not evaluated"
when one is issued (a guide stopped before it fits is not a like-for-like comparison:
AutoNormal after 50 steps is flagged on 568 of 1000 units, after 300 on none). Figures:

* ``steps_per_s``: ``num_steps`` / total wall time of one call. For infer_state this
  includes its validation, guide set-up and posterior summaries; for plain Pyro, guide
  set-up and the step loop.
* ``steps_per_s_loop``: the step loop alone, ``(num_steps - short) / (T(num_steps) -
  T(short))`` from the medians of full and short runs (set-up and summaries cancel); the
  short runs are long enough to fit too.
* ``ratio``: ``steps_per_s`` of infer_state / plain Pyro (target >= 1 / 1.3); ``ratio_cpu``
  the same by the CPU time of the calling thread (one torch thread), which the load of a
  shared machine moves far less.

The two are run alternately within each repeat so load changes hit both.
"""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass
from typing import Any

import pyro
import pyro.distributions as dist
import torch
from pyro.infer import SVI, Trace_ELBO
from pyro.infer.autoguide import AutoNormal
from pyro.optim import ClippedAdam
from torch import Tensor
from tqdm.auto import tqdm

from inference.diagnostics import PoorPosteriorWarning
from inference.state import SVIOptions, infer_state
from models.graph import CausalGraph
from models.mechanisms import LinearMechanism
from models.variables import Role, Variable
from models.world import WorldModel
from pal.checks import check_int
from pal.lab.registry import register
from pal.lab.report import Precondition, Report, Table, Target
from pal.lab.timing import measure_interleaved, ratio, torch_threads

__all__ = ["SIGMAS", "WEIGHTS", "Config", "chain4_model", "plain_program", "run"]

log = logging.getLogger(__name__)

WEIGHTS = {"b": 0.8, "c": -1.2, "d": 0.5}
SIGMAS = {"b": 1.0, "c": 0.5, "d": 0.5}
OBSERVED = ("a", "c", "d")


@dataclass(frozen=True)
class Config:
    """Sizes and SVI settings (infer_state's defaults).

    Attributes:
        seed: data and SVI seed.
        units: number of units N.
        num_steps: SVI steps of each call.
        short_steps: steps of the short runs that isolate the step loop.
        svi: the SVI settings of both (``lr``, ``lr_final``, ``num_particles``, ``init_scale``).
        repeats: timed repeats (median reported) after one warm-up of each.
        threads: torch threads during the run (None: leave as is).
    """

    seed: int = 0
    units: int = 1000
    num_steps: int = 600
    short_steps: int = 300
    svi: SVIOptions = SVIOptions()
    repeats: int = 5
    threads: int | None = 1

    def __post_init__(self) -> None:
        check_int("units", self.units)
        check_int("num_steps", self.num_steps, minimum=2)
        check_int("short_steps", self.short_steps, maximum=self.num_steps - 1)
        check_int("repeats", self.repeats)
        if not isinstance(self.svi, SVIOptions):
            raise ValueError(f"svi must be an SVIOptions, got {type(self.svi).__name__}")


def chain4_model() -> WorldModel:
    """The A -> B -> C -> D world model with ``WEIGHTS`` and ``SIGMAS``; B latent."""
    graph = CausalGraph(
        [
            Variable("a", Role.OBSERVED),
            Variable("b", Role.LATENT),
            Variable("c", Role.OBSERVED),
            Variable("d", Role.OBSERVED),
        ],
        [("a", "b"), ("b", "c"), ("c", "d")],
    )
    mechs = {k: LinearMechanism.from_coefficients([[w]], sigma=SIGMAS[k]) for k, w in WEIGHTS.items()}
    return WorldModel(graph, mechs)


def plain_program(a: Tensor, c: Tensor, d: Tensor) -> None:
    """The same model as a hand-written Pyro program; values ``(N, 1)``."""
    n = a.shape[0]
    with pyro.plate("units", n, dim=-1):
        a = pyro.sample("a", dist.Normal(torch.zeros(1), torch.ones(1)).expand([n, 1]).to_event(1), obs=a)
        b = pyro.sample("b", dist.Normal(WEIGHTS["b"] * a, SIGMAS["b"]).to_event(1))
        c = pyro.sample("c", dist.Normal(WEIGHTS["c"] * b, SIGMAS["c"]).to_event(1), obs=c)
        pyro.sample("d", dist.Normal(WEIGHTS["d"] * c, SIGMAS["d"]).to_event(1), obs=d)


def _plain_svi(config: Config, data: dict[str, Tensor], num_steps: int) -> float:
    """What a user writes by hand: returns the final loss per unit."""
    n = data["a"].shape[0]
    with pyro.get_param_store().scope(), torch.random.fork_rng():
        torch.manual_seed(config.seed)  # Pyro samples with torch's RNG; numpy's and Python's stay untouched
        s = config.svi
        guide = AutoNormal(plain_program, init_scale=s.init_scale)
        optim = ClippedAdam({"lr": s.lr, "lrd": (s.lr_final / s.lr) ** (1.0 / num_steps)})
        elbo = Trace_ELBO(
            num_particles=s.num_particles,
            vectorize_particles=s.num_particles > 1,
            max_plate_nesting=1,
        )
        svi = SVI(plain_program, guide, optim, elbo)
        loss = math.nan
        for _ in range(num_steps):
            loss = svi.step(data["a"], data["c"], data["d"]) / n
    return loss


def _ours(
    config: Config, model: WorldModel, data: dict[str, Tensor], num_steps: int, flagged: list[str]
) -> float:
    """infer_state's final loss per unit; the messages of its PoorPosteriorWarnings go to ``flagged``."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", PoorPosteriorWarning)
        result = infer_state(model, data, num_steps=num_steps, options=config.svi, seed=config.seed)
    for w in caught:
        if issubclass(w.category, PoorPosteriorWarning):
            flagged.append(f"{num_steps} steps: {w.message}")
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return result.losses[-1]


@register(
    "svi",
    kind="bench",
    config=Config,
    quick=Config(units=100, num_steps=300, short_steps=150, svi=SVIOptions(num_particles=4), repeats=1),
    tiny=Config(units=20, num_steps=6, short_steps=2, svi=SVIOptions(num_particles=2), repeats=1),
)
def run(config: Config, progress_bar: bool = False) -> Report:
    """State inference: infer_state's SVI steps/s against the same SVI written in plain Pyro."""
    with torch_threads(config.threads):
        model = chain4_model()
        sample = model.sample(config.units, torch.Generator().manual_seed(config.seed))
        data = {k: sample[k] for k in OBSERVED}
        timings = {}
        flagged: list[str] = []
        bar = tqdm(total=2, desc="bench svi", disable=not progress_bar, leave=False)
        for label, steps, warmup in (("short", config.short_steps, 1), ("full", config.num_steps, 0)):
            log.info("timing %d-step runs (%d repeats)", steps, config.repeats)
            timings[label] = measure_interleaved(
                {
                    "infer_state": lambda s=steps: _ours(config, model, data, s, flagged),
                    "plain_pyro": lambda s=steps: _plain_svi(config, data, s),
                },
                repeats=config.repeats,
                warmup=warmup,
            )
            bar.update()
        bar.close()
    return _report(config, timings["full"], timings["short"], flagged)


def _report(config: Config, full: dict[str, Any], short: dict[str, Any], flagged: list[str]) -> Report:
    """Rates, the loop-only rates, the final losses and the target (not evaluated after a warning)."""
    loss = {k: float(t.result) for k, t in full.items()}
    if not math.isclose(loss["infer_state"], loss["plain_pyro"], rel_tol=1e-3, abs_tol=1e-3):
        log.warning(
            "infer_state and plain Pyro end at different losses per unit: %.6g vs %.6g (same seed and "
            "settings should give the same trajectory)",
            loss["infer_state"],
            loss["plain_pyro"],
        )
    extra = config.num_steps - config.short_steps
    loop = {}
    for name in full:
        delta = full[name].median - short[name].median
        loop[name] = extra / delta if delta > 0 else None
        if loop[name] is None:
            log.warning("%s: the full run was not slower than the short one (noise); no loop rate", name)
    rate = {k: config.num_steps / t.median for k, t in full.items()}
    cpu = {k: t.cpu_median for k, t in full.items()}
    seconds = {k: t.median for k, t in full.items()}
    rel = rate["infer_state"] / rate["plain_pyro"]
    rel_cpu = ratio(cpu["plain_pyro"], cpu["infer_state"])
    loop_ratio = ratio(loop["infer_state"], loop["plain_pyro"])
    rows = [(name, seconds[name], cpu[name], rate[name], loop[name], loss[name]) for name in rate]
    c = config
    return Report(
        title="SVI benchmark",
        metrics={
            "steps_per_s": rate,
            "steps_per_s_loop": loop,
            "ratio": rel,
            "ratio_cpu": rel_cpu,
            "loop_ratio": loop_ratio,
            "seconds": seconds,
            "cpu_seconds": cpu,
            "final_loss": loss,
            "pal_warnings": sorted(set(flagged)),
        },
        tables=[
            Table(
                "infer_state against plain Pyro SVI",
                (
                    "",
                    "seconds per call",
                    "CPU s per call",
                    "steps/s",
                    "steps/s (loop only)",
                    "final loss / unit",
                ),
                rows,
                caption="ratio > 1 means infer_state is faster.",
            )
        ],
        targets=[
            Target(
                name,
                value,
                1 / 1.3,
                ">=",
                f"steps per {clock} second of infer_state / of plain Pyro",
                Precondition(
                    not flagged, "infer_state issued no PoorPosteriorWarning in any run (a fitted guide)"
                ),
            )
            for name, value, clock in (("ratio", rel, "wall"), ("ratio_cpu", rel_cpu, "CPU"))
        ],
        notes=[
            f"A -> B -> C -> D, B latent, {c.units} units, {c.num_steps} steps, {c.svi.num_particles} particles, "
            f"AutoNormal + ClippedAdam; torch threads: {c.threads}.",
            "infer_state's posterior diagnostics: "
            + ("no PoorPosteriorWarning in any run." if not flagged else "; ".join(sorted(set(flagged)))),
        ],
    )
