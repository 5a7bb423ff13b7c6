"""``--engine ray``: babbling shards as Ray tasks and sweep runs as Ray Tune trials.

The only module of pal that imports Ray (the optional extra, ``pip install ".[ray]"``); the
command line imports it only for ``--engine ray``. It runs the same work as the local engine:

- babbling: :func:`pal.sim.shards.run_shard` for each shard of
  :func:`pal.sim.shards.shard_configs`, one Ray task (1 CPU) per shard, into the same shard
  directories, merged by :func:`pal.sim.shards.babble_sharded` as before;
- sweeps: one function trainable per run (a ``grid_search`` over the runs to do) calling
  :func:`pal.lab.sweep.compute_run`; a Tune callback in this process writes each
  run's report or error record with :func:`pal.lab.sweep.record_run` as its result
  arrives, so ``runs/``, the summary and ``--retry-failed`` are those of the local engine.
  Tune's own directory is a temporary directory inside the sweep's, removed afterwards; its
  loggers and progress output are off.

Ray runs on an existing cluster (``address``, as for ``ray.init(address=...)``) or on a local
one started with ``cpus`` CPUs. The local one keeps its session files (logs, sockets) in a
temporary directory removed at the end (``ray.init(_temp_dir=...)``, not ``/tmp/ray``), uses a
fresh token of Ray's token authentication (``RAY_AUTH_TOKEN`` for the length of the block,
nothing written to ``~/.ray``) and logs at level ERROR (no warning that token authentication
is on). An address is probed first, within ``timeout`` seconds: a TCP
connection to ``host:port``, then ``ray.init`` in a child process that is killed when the
time is up (``ray.init`` itself retries for minutes). Workers write the shard and sweep
directories at the paths given here, so on a multi-node cluster those must be on storage
every node sees at the same path.
"""

from __future__ import annotations

import json
import logging
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import ray
from ray import tune

from pal.lab import sweep as sweeps

__all__ = ["RayEngine", "RayEngineError", "probe"]

log = logging.getLogger(__name__)

_PROBE = (
    "import json, sys, ray\n"
    "ray.init(address=sys.argv[1], logging_level='error', log_to_driver=False)\n"
    "print(json.dumps(ray.cluster_resources().get('CPU', 0)))\n"
    "ray.shutdown()\n"
)


class RayEngineError(ValueError):
    """Ray cannot be used: an address that does not answer, or a run Ray could not finish."""


def _host_port(address: str) -> tuple[str, int] | None:
    """``(host, port)`` of ``host:port`` or ``ray://host:port``; None for ``auto`` and the like."""
    text = address.removeprefix("ray://")
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit():
        return None
    return host.strip("[]"), int(port)


def probe(address: str, timeout: float) -> float:
    """Check that a Ray cluster answers at ``address`` within ``timeout`` seconds.

    Returns:
        The cluster's CPUs.

    Raises:
        RayEngineError: nothing listens there, or no Ray cluster answered in time (one line).
    """
    if not timeout > 0:
        raise RayEngineError(f"--ray-timeout must be > 0 seconds, got {timeout}")
    start = time.monotonic()
    hint = "start one with `ray start --head` or leave out --ray-address for a local Ray"
    target = _host_port(address)
    if target is not None:
        try:
            socket.create_connection(target, timeout=timeout).close()
        except OSError as err:
            raise RayEngineError(f"Ray address {address!r} does not answer ({err}); {hint}") from None
    left = max(timeout - (time.monotonic() - start), 0.1)
    child = subprocess.Popen(
        [sys.executable, "-c", _PROBE, address],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group: killed with whatever it started
    )
    try:
        out, err = child.communicate(timeout=left)
    except subprocess.TimeoutExpired:
        os.killpg(child.pid, signal.SIGKILL)
        child.communicate()
        raise RayEngineError(
            f"Ray address {address!r} did not answer within {timeout:g} s (--ray-timeout); {hint}"
        ) from None
    if child.returncode != 0:
        lines = [line for line in err.splitlines() if line.strip()]
        why = lines[-1].strip() if lines else f"exit status {child.returncode}"
        raise RayEngineError(f"Ray address {address!r}: {why}; {hint}")
    return float(json.loads(out.strip().splitlines()[-1]))


def _log_unremoved(_fn: Any, path: str, exc_info: Any) -> None:
    log.warning("could not remove the local Ray's file %s: %s", path, exc_info[1])


class RayEngine:
    """A connection to Ray for the length of a ``with`` block.

    Args:
        address: an existing cluster (``ray.init(address=...)``), or None for a local Ray.
        timeout: seconds an address has to answer (:func:`probe`).
        cpus: CPUs of the local Ray (None: all of this machine); unused with ``address``.

    If Ray is already initialised in this process (a notebook, a test), that connection is
    used and left open; otherwise the block connects or starts Ray and shuts it down at its end.
    """

    def __init__(self, address: str | None = None, *, timeout: float = 30.0, cpus: int | None = None):
        self.address, self.timeout, self.cpus = address, timeout, cpus
        self._owner = False
        self._temp: str | None = None  # the local Ray's session directory
        self._env: dict[str, str | None] = {}  # environment variables to restore at the end

    def __enter__(self) -> RayEngine:
        if self.address is not None:
            probe(self.address, self.timeout)
        if ray.is_initialized():
            log.info("using the Ray already initialised in this process")
            return self
        if self.address is not None:
            ray.init(address=self.address, logging_level=logging.WARNING, log_to_driver=False)
        else:
            self._start_local()
        self._owner = True
        log.info("Ray: %s CPUs", ray.cluster_resources().get("CPU"))
        return self

    def _start_local(self) -> None:
        """``ray.init`` of a local Ray: own session directory and token, log level ERROR."""
        env = {}
        if not (os.environ.get("RAY_AUTH_TOKEN") or os.environ.get("RAY_AUTH_TOKEN_PATH")):
            env["RAY_AUTH_TOKEN"] = secrets.token_hex(32)  # else Ray writes one to ~/.ray/auth_token
        self._env = {k: os.environ.get(k) for k in env}
        os.environ.update(env)
        # Ray's own base directory (RAY_TMPDIR, else /tmp on macOS: short socket paths)
        base = os.environ.get("RAY_TMPDIR") or ("/tmp" if sys.platform == "darwin" else None)
        self._temp = tempfile.mkdtemp(prefix="pal-ray-", dir=base)
        try:
            ray.init(
                num_cpus=self.cpus,
                include_dashboard=False,
                logging_level=logging.ERROR,
                log_to_driver=False,
                _temp_dir=self._temp,
            )
        except BaseException:
            self._clean_up()
            raise

    def _clean_up(self) -> None:
        for key, value in self._env.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        self._env = {}
        if self._temp is not None:
            shutil.rmtree(self._temp, onerror=_log_unremoved)
            self._temp = None

    def __exit__(self, *exc: object) -> None:
        if self._owner:
            ray.shutdown()
            self._owner = False
            self._clean_up()

    def map(self, fn: Callable[..., Any], args: Sequence[tuple[Any, ...]]) -> list[Any]:
        """``[fn(*a) for a in args]`` as Ray tasks of 1 CPU each, results in order.

        Raises:
            The task's own exception (e.g. the ``ValueError`` of a shard that cannot resume),
            or RayEngineError if a worker died.
        """
        task = ray.remote(num_cpus=1, max_retries=0)(fn)
        refs = [task.remote(*a) for a in args]
        try:
            return ray.get(refs)
        except ray.exceptions.RayTaskError as err:
            cause = err.cause
            if isinstance(cause, Exception):
                raise cause from None
            raise RayEngineError(str(err).splitlines()[0]) from None
        except ray.exceptions.RayError as err:  # a worker or node died
            raise RayEngineError(f"Ray task failed: {str(err).splitlines()[0]}") from None

    def sweep_runs(self, plan: sweeps.SweepPlan, todo: list[sweeps.Run], out: Path) -> None:
        """Run ``todo`` of ``plan`` as Tune trials; each run's report or error lands in ``out/runs``."""
        from pal.lab import registry

        entry = registry.get(plan.kind, plan.name)
        runs = [(r.settings, r.seed) for r in todo]
        trainable = tune.with_parameters(_trial, entry=entry, base=plan.base, sets=list(plan.sets), runs=runs)
        recorder = _Recorder(out, todo)
        previous = os.environ.get("TUNE_DISABLE_AUTO_CALLBACK_LOGGERS")
        os.environ["TUNE_DISABLE_AUTO_CALLBACK_LOGGERS"] = "1"  # no CSV/JSON/TensorBoard files
        try:
            with tempfile.TemporaryDirectory(prefix=".tune-", dir=out.resolve()) as storage:
                tuner = tune.Tuner(
                    trainable,
                    param_space={"index": tune.grid_search(list(range(len(todo))))},
                    tune_config=tune.TuneConfig(reuse_actors=True, trial_dirname_creator=_dirname),
                    run_config=tune.RunConfig(
                        name=plan.name, storage_path=storage, verbose=0, callbacks=[recorder]
                    ),
                )
                tuner.fit()
        finally:
            if previous is None:
                os.environ.pop("TUNE_DISABLE_AUTO_CALLBACK_LOGGERS", None)
            else:
                os.environ["TUNE_DISABLE_AUTO_CALLBACK_LOGGERS"] = previous
        for i, run in enumerate(todo):  # a trial that never reported is failed, not dropped
            if i not in recorder.done:
                sweeps.record_run(out, run, None, "Ray Tune trial ended without a result")


def _dirname(trial: Any) -> str:
    return f"run_{trial.config['index']:03d}"


def _trial(
    config: dict[str, Any],
    entry: Any = None,
    base: sweeps.Base = "default",
    sets: Sequence[str] = (),
    runs: Sequence[tuple[dict[str, Any], int]] = (),
) -> None:
    """The function trainable of one sweep run (in a Ray worker): run it, report its document."""
    import torch

    torch.set_num_threads(1)  # as the local engine's workers: small tensors, shared cores
    index = config["index"]
    settings, seed = runs[index]
    document, error = sweeps.compute_run(entry, base, sets, settings, seed)
    tune.report(
        {"index": index, "document": "" if document is None else json.dumps(document), "error": error or ""}
    )


class _Recorder(tune.Callback):
    """Writes each run's report or error record in the driver, as its result arrives."""

    def __init__(self, out: Path, todo: list[sweeps.Run]):
        self.out, self.todo, self.done = out, todo, set()

    def on_trial_result(self, iteration: int, trials: list, trial: Any, result: dict, **info: Any) -> None:
        index = int(result["index"])
        document = json.loads(result["document"]) if result["document"] else None
        sweeps.record_run(self.out, self.todo[index], document, result["error"] or None)
        self.done.add(index)

    def on_trial_error(self, iteration: int, trials: list, trial: Any, **info: Any) -> None:
        index = int(trial.config["index"])
        error = trial.get_error()
        lines = [line for line in str(error or "").splitlines() if line.strip()]
        why = lines[-1].strip() if lines else "unknown error"
        sweeps.record_run(self.out, self.todo[index], None, f"Ray Tune trial failed: {why}")
        self.done.add(index)
