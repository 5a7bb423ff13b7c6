"""The ``pal`` command.

pal demo [--quick] [--out DIR]
pal list
pal experiment NAME [--quick] [--json] [--out DIR] [--set KEY=VALUE ...] [BODY OPTIONS] [--dataset DIR]
pal bench NAME [same options]
pal loop [--steps N] [--video out.mp4] [--babble B] [--goal X,Y] [--seed S] [--json] [--out DIR]
pal babble [BODY OPTIONS] [--joint J ...] --steps N --seed S --out DIR [--policy uniform|ou] [--workers N]
           [--engine local|ray] [--ray-address ADDRESS] [--ray-timeout S] [--probe-steps N] [--resume] [--json]
pal sweep NAME --grid KEY=V1,V2 ... --seeds 0-9 --out DIR [--quick|--tiny] [--set KEY=VALUE ...] [--workers N]
          [--engine local|ray] [--ray-address ADDRESS] [--ray-timeout S] [--retry-failed]
pal record --motion MOTION --seed S --out DIR [--fps F] [--width W] [--height H] [--overwrite] [--json]

BODY OPTIONS: ``--body finger|arm | --mjcf PATH``, ``--name NAME``, ``--joint J``,
``--actuator A ...``, ``--frame-skip N``, ``--action-range A=LOW,HIGH ...``, ``--effective-range``.

Every usage error (a bad flag, an unknown name, a setting of the wrong type, an unusable
``--out``) is one line on stderr and exit status 2, reported before any work starts.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pal.cli_args import babble_steps, check_dataset_dir, fps, out_dir, seed
from pal.cli_body import UsageError, UsageParser, action_ranges, add_body_flags, body_fields, check_data
from pal.cli_engine import add_engine_flags, connected, ray_engine
from pal.lab.runner import log_like

__all__ = ["UsageError", "build_parser", "main"]

log = logging.getLogger("pal")

#: What ``ArgumentParser.add_subparsers`` returns; argparse keeps its class private.
Subparsers = Any


def _configure(verbose: bool, threads: int, quiet: bool = False) -> None:
    """Threads and logging: DEBUG with ``-v``, else WARNING for ``quiet`` commands (the demo), else INFO."""
    os.environ.setdefault("MPLBACKEND", "Agg")
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(var, str(threads))  # before numpy/torch load their thread pools
    import torch

    # The models work on small tensors: one intra-op thread is faster, and OpenMP threads
    # slow down by orders of magnitude when another process holds the second core.
    torch.set_num_threads(threads)
    level = logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO
    log_like(level)  # basicConfig, and the level also when the root logger has handlers (main() in a test)
    for noisy in ("matplotlib", "PIL", "OpenGL", "numexpr", "h5py", "jax"):
        logging.getLogger(noisy).setLevel(logging.WARNING)


def _output_dir(out: str | None) -> Path | None:
    from pal.lab.runner import OutputError, check_output_dir

    if out is None:
        return None
    try:
        return check_output_dir(out)
    except OutputError as err:
        raise UsageError(str(err)) from None


def _run_entry(kind: str, name: str, args: argparse.Namespace, fields: dict[str, Any] | None = None) -> int:
    from pal.lab import registry, render
    from pal.lab.runner import configure, execute

    try:
        entry = registry.get(kind, name)
    except ValueError as err:
        raise UsageError(str(err)) from None
    try:
        config = configure(
            entry,
            quick=getattr(args, "quick", False),
            tiny=getattr(args, "tiny", False),
            sets=getattr(args, "set", None) or (),
            fields={**body_fields(entry, args), **(fields or {})},
        )
    except ValueError as err:  # unknown setting, wrong type, or refused by the config's checks
        raise UsageError(f"pal {kind} {name}: {err}") from None
    check_data(kind, name, config)
    out = _output_dir(args.out)
    record = execute(entry, config, progress_bar=not args.json and sys.stderr.isatty())
    if out is not None:
        paths = render.write(record, out)
        log.info("wrote %s", ", ".join(str(p) for p in paths.values()))
    if args.json:
        print(json.dumps(render.document(record), indent=2, sort_keys=True, allow_nan=False))
    else:
        print(render.markdown(record))
    return 0


def _demo(args: argparse.Namespace) -> int:
    from pal.lab import demo

    out = _output_dir(args.out)
    start = time.perf_counter()

    def started(i: int, n: int, kind: str, name: str) -> None:
        print(f"pal demo: {kind} {name} ({i}/{n}) ...", file=sys.stderr, flush=True)

    for text in demo.run(out, quick=args.quick, progress_bar=sys.stderr.isatty(), started=started):
        print(text, flush=True)
    print(f"\n(pal demo took {time.perf_counter() - start:.1f} s; reports and figures in {out})")
    return 0


def _list(args: argparse.Namespace) -> int:
    from pal.lab import registry

    for entry in registry.entries():
        print(f"pal {entry.kind:<10} {entry.name:<16} {entry.summary}")
    return 0


def _loop(args: argparse.Namespace) -> int:
    fields: dict[str, Any] = {"steps": args.steps, "seed": args.seed}
    if args.babble is not None:
        fields["babble"] = args.babble
    if args.goal is not None:
        try:
            goal = tuple(float(v) for v in args.goal.split(","))
        except ValueError:
            raise UsageError(f"--goal {args.goal!r}: expected X,Y in metres, e.g. --goal 0.05,0.15") from None
        if len(goal) != 2:
            raise UsageError(f"--goal {args.goal!r}: expected two numbers X,Y in metres")
        fields["goal"] = goal
    if args.video is not None:
        if not str(args.video).endswith(".mp4"):
            raise UsageError(f"--video {args.video!r}: expected a path ending in .mp4")
        parent = Path(args.video).resolve().parent
        _output_dir(str(parent))
        fields["video"] = str(args.video)
    return _run_entry("experiment", "loop", args, fields)


def _babble_run(config: Any, args: argparse.Namespace, out: Path, engine: Any) -> Any:
    """Babble ``config`` into ``out``: sharded, as one Ray task, or in this process."""
    from pal.sim.babbling import babble
    from pal.sim.shards import babble_sharded

    try:
        if args.workers > 1:
            dataset = babble_sharded(
                config,
                args.out,
                workers=args.workers,
                resume=args.resume,
                backend=args.backend,
                map_shards=None if engine is None else engine.map,
            )
        elif engine is not None:  # the one run as one Ray task: the same data as in this process
            from pal.io.dataset import TransitionDataset
            from pal.sim.shards import run_shard

            engine.map(run_shard, [(config, str(out.resolve()), args.resume, args.backend)])
            dataset = TransitionDataset.load(out)
        else:
            dataset = babble(
                config, args.out, resume=args.resume, progress_bar=sys.stderr.isatty(), backend=args.backend
            )
    except ValueError as err:  # an occupied, locked or corrupted directory
        raise UsageError(f"pal babble: {err}") from None
    return dataset


def _babble(args: argparse.Namespace) -> int:
    from pal.sim.babbling import BabbleConfig, check_config
    from pal.sim.shards import shard_configs

    if args.mjcf and args.body:
        raise UsageError("give either --body or --mjcf, not both")
    if args.workers < 1:
        raise UsageError(f"pal babble: --workers must be >= 1, got {args.workers}")
    engine = ray_engine("babble", args)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {args.out!r} is a file, expected a dataset directory")
    check_dataset_dir(out)
    try:
        config = BabbleConfig(
            body=args.mjcf or args.body or "finger",
            joints=tuple(args.joint) if args.joint else None,
            actuators=tuple(args.actuator) if args.actuator else None,
            steps=args.steps,
            seed=args.seed,
            policy=args.policy,
            frame_skip=args.frame_skip,
            reset_every=args.reset_every,
            chunk_size=args.chunk_size,
            name=args.body_name,
            action_ranges=action_ranges(args.action_range),
            effective_range=args.effective_range,
            probe_steps=args.probe_steps,
        )
        check_config(config)  # names, ranges and the file, before the directory is touched
        if args.workers > 1:
            shard_configs(config, args.workers)
    except ValueError as err:  # bad sizes, names, ranges or MJCF
        raise UsageError(f"pal babble: {err}") from None
    _output_dir(args.out)
    with connected("babble", engine):
        start = time.perf_counter()
        dataset = _babble_run(config, args, out, engine)
    meta = dataset.metadata
    q = {j: dataset.columns[f"q.{j}"][:, 0] for j in dataset.joints}
    summary = {
        "out": str(args.out),
        "rows": len(dataset),
        "body": meta["body"],
        "mjcf_path": meta["mjcf_path"],
        "frame_skip": meta["frame_skip"],
        "dt": meta["dt"],
        "joints": dataset.joints,
        "actuators": dataset.actuators,
        "action_ranges": meta["action_ranges"],
        "effective_ranges": meta["effective_ranges"],
        "q": {
            j: {"min": float(v.min()), "max": float(v.max()), "mean": float(v.mean()), "std": float(v.std())}
            for j, v in q.items()
        },
    }
    if args.json:
        print(json.dumps(summary, indent=2, sort_keys=True, allow_nan=False))
        return 0
    print(
        f"{len(dataset)} transitions of {summary['body']!r} in {args.out} ({time.perf_counter() - start:.1f} s; "
        f"step {summary['dt']:.3g} s = {summary['frame_skip']} MuJoCo steps)"
    )
    for j, st in summary["q"].items():
        print(f"  q.{j}: [{st['min']:.3f}, {st['max']:.3f}], mean {st['mean']:.3f}, std {st['std']:.3f}")
    for a in dataset.actuators:
        e = summary["effective_ranges"][a]
        lo, hi = e["effective"]
        print(
            f"  {a}: babbled [{e['babbled'][0]:.3g}, {e['babbled'][1]:.3g}], effective [{lo:.3g}, {hi:.3g}] "
            f"({100 * e['saturated_fraction']:.0f} % saturated)"
        )
    return 0


def _sweep(args: argparse.Namespace) -> int:
    from pal.lab import sweep

    if args.workers < 1:
        raise UsageError(f"pal sweep: --workers must be >= 1, got {args.workers}")
    engine = ray_engine("sweep", args)
    base = "quick" if args.quick else "tiny" if args.tiny else "default"
    try:
        if args.retry_failed and not args.grid and args.seeds is None:
            plan = None
        else:
            plan = sweep.plan(args.name, args.grid or (), args.seeds or "0", base=base, sets=args.set or ())
        _output_dir(args.out)
        with connected("sweep", engine):
            if engine is None:
                result = sweep.run_sweep(plan, args.out, retry_failed=args.retry_failed, workers=args.workers)
            else:
                result = sweep.run_sweep(
                    plan, args.out, retry_failed=args.retry_failed, engine=engine.sweep_runs
                )
    except sweep.SweepError as err:
        raise UsageError(f"pal sweep: {err}") from None
    for key in ("markdown", "pooled.markdown"):  # pooled: an entry whose report pools the seeds
        if key in result.paths:
            print(result.paths[key].read_text(encoding="utf-8"))
    if "pooled" in result.failed:
        print(f"The pooled report failed: {result.failed['pooled'][2]}")
    print(f"(wrote {', '.join(str(p) for p in result.paths.values())})")
    return 1 if result.failed else 0


def _record(args: argparse.Namespace) -> int:
    from pal.perception import RecordedSequence
    from pal.sim.recording import RecordConfig, record

    if (Path(args.out) / "sequence.json").exists() and not args.overwrite:
        raise UsageError(f"{args.out} already holds a sequence; pass --overwrite to replace it")
    try:
        config = RecordConfig(
            args.motion,
            seed=args.seed,
            fps=args.fps,
            width=args.width,
            height=args.height,
            depth_noise=args.depth_noise,
            rgb_noise=args.rgb_noise,
        )
    except ValueError as err:  # unknown motion, bad sizes
        raise UsageError(f"pal record: {err}") from None
    _output_dir(args.out)
    start = time.perf_counter()
    try:
        path = record(
            config, args.out, overwrite=args.overwrite, progress_bar=not args.json and sys.stderr.isatty()
        )
    except ValueError as err:  # an occupied directory
        raise UsageError(f"pal record: {err}") from None
    seq = RecordedSequence(path)
    summary = {
        "out": str(path),
        "motion": args.motion,
        "seed": args.seed,
        "frames": len(seq),
        "object": seq.metadata["object"],
        "gt_objects": list(seq.gt_objects),
        "backend": seq.metadata.get("backend"),
    }
    if args.json:
        print(json.dumps(summary, indent=2, sort_keys=True))
    else:
        print(
            f"{len(seq)} frames of {args.motion!r} (seed {args.seed}) in {path} ({time.perf_counter() - start:.1f} s)"
        )
    return 0


def _add_run_flags(p: argparse.ArgumentParser, *, body: bool = True) -> None:
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--out", type=out_dir, default=None, help="directory for JSON, markdown, PNG figures")
    if body:
        size = p.add_mutually_exclusive_group()
        size.add_argument("--quick", action="store_true", help="small configuration")
        size.add_argument("--tiny", action="store_true", help="the smallest configuration (the tests')")
        p.add_argument(
            "--set",
            action="append",
            metavar="KEY=VALUE",
            help="override a setting by its dotted path, e.g. protocol.fit.schedule.epochs=40",
        )
        add_body_flags(p, babble=False)
        p.add_argument(
            "--dataset", default=None, metavar="DIR", help="use this babbling dataset instead of babbling"
        )


def _add_demo_parser(sub: Subparsers) -> None:
    """``pal demo``."""
    p = sub.add_parser("demo", help="short end-to-end run: prints reports (log lines with -v), saves figures")
    p.add_argument("--out", type=out_dir, default="pal-demo", help="reports and figures (default: pal-demo)")
    p.add_argument("--quick", action="store_true", help="smallest sizes")
    p.set_defaults(func=_demo, quiet=True)  # tables and progress only; log lines with -v


def _add_list_parser(sub: Subparsers) -> None:
    """``pal list``."""
    p = sub.add_parser("list", help="list the registered experiments and benchmarks")
    p.set_defaults(func=_list)


def _add_run_parsers(sub: Subparsers) -> None:
    """``pal bench`` and ``pal experiment``."""
    for kind, help_text in (("bench", "run a benchmark"), ("experiment", "run an experiment")):
        p = sub.add_parser(kind, help=help_text)
        p.add_argument("name")
        _add_run_flags(p)
        p.set_defaults(func=lambda a, k=kind: _run_entry(k, a.name, a))


def _add_loop_parser(sub: Subparsers) -> None:
    """``pal loop``."""
    p = sub.add_parser("loop", help="the closed perception-action loop (= pal experiment loop)")
    p.add_argument("--steps", type=int, default=60, help="loop steps, babbling included (default 60)")
    p.add_argument(
        "--babble", type=int, default=None, help="babbling steps before the first fit (default half)"
    )
    p.add_argument(
        "--video", default=None, metavar="PATH", help="write an mp4 with the detections and targets"
    )
    p.add_argument("--goal", default=None, metavar="X,Y", help="push the box to this table position, m")
    p.add_argument("--seed", type=seed, default=0, help="run seed, 0 to 2**32 - 1 (default 0)")
    _add_run_flags(p, body=False)
    p.set_defaults(func=_loop)


def _add_babble_parser(sub: Subparsers) -> None:
    """``pal babble``."""
    p = sub.add_parser("babble", help="record motor-babbling transitions to a dataset directory")
    add_body_flags(p, babble=True)
    p.add_argument(
        "--steps", type=babble_steps, default=100_000, help="transitions, <= 10**8 (default 100000)"
    )
    p.add_argument("--seed", type=seed, default=0, help="run seed, 0 to 2**32 - 1 (default 0)")
    p.add_argument("--out", type=out_dir, required=True, help="dataset directory")
    p.add_argument(
        "--policy", choices=["uniform", "ou"], default="uniform", help="babbling policy (default uniform)"
    )
    p.add_argument(
        "--probe-steps", type=int, default=2000, help="steps of the --effective-range probe (default 2000)"
    )
    p.add_argument("--reset-every", type=int, default=10_000, help="environment reset period (default 10000)")
    p.add_argument("--chunk-size", type=int, default=10_000, help="rows per chunk file (default 10000)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted run in --out")
    p.add_argument(
        "--workers",
        type=int,
        default=1,
        help="split the run into N seeded shards babbled by N local processes, merged into --out (default 1)",
    )
    add_engine_flags(p, "the shards run in local processes or as Ray tasks")
    p.add_argument(
        "--backend",
        choices=["loop", "rollout"],
        default="loop",
        help="physics stepping: mj_step from Python or mujoco.rollout (same data; default loop)",
    )
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(func=_babble)


def _add_sweep_parser(sub: Subparsers) -> None:
    """``pal sweep``."""
    p = sub.add_parser(
        "sweep", help="run an experiment over a grid of settings x seeds: mean ± sd table, figures"
    )
    p.add_argument("name", help="registered experiment")
    p.add_argument(
        "--grid", action="append", metavar="KEY=V1,V2", help="swept setting and its values (repeatable)"
    )
    p.add_argument("--seeds", default=None, help="seeds of every cell: 0-9, 0,3,7; at most 10000 (default 0)")
    p.add_argument("--out", type=out_dir, required=True, help="sweep directory: runs, summaries, figures")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--quick", action="store_true", help="start from the quick config")
    group.add_argument("--tiny", action="store_true", help="start from the tiny (test) config")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="fixed setting of every run")
    workers = "local processes, or local Ray CPUs (default 1: in this process)"
    p.add_argument("--workers", type=int, default=1, help=workers)
    add_engine_flags(p, "runs go through local processes or Ray Tune")
    p.add_argument("--retry-failed", action="store_true", help="run only the failed runs of --out again")
    p.set_defaults(func=_sweep)


def _add_record_parser(sub: Subparsers) -> None:
    """``pal record``."""
    p = sub.add_parser("record", help="record a scripted tabletop run as an RGB-D sequence with ground truth")
    p.add_argument("--motion", required=True, help="scripted motion of thesis Table 5.1, e.g. box-rotation")
    p.add_argument("--seed", type=seed, default=0, help="run seed: path, speed, sensor noise (default 0)")
    p.add_argument("--out", type=out_dir, required=True, help="sequence directory")
    p.add_argument("--fps", type=fps, default=15.0, help="frames per second, at most 1000 (default 15)")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument(
        "--depth-noise", type=float, default=0.002, help="depth noise std at 1 m, metres (default 0.002)"
    )
    p.add_argument("--rgb-noise", type=float, default=2.0, help="colour noise std, grey levels (default 2)")
    p.add_argument("--overwrite", action="store_true", help="replace a sequence already in --out")
    p.add_argument("--json", action="store_true", help="print a JSON summary")
    p.set_defaults(func=_record)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of ``pal``."""
    parser = UsageParser(prog="pal", description="Causal perception-action learning toolkit.")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging and tracebacks")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=UsageParser)
    _add_demo_parser(sub)
    _add_list_parser(sub)
    _add_run_parsers(sub)
    _add_loop_parser(sub)
    _add_babble_parser(sub)
    _add_sweep_parser(sub)
    _add_record_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``pal``; returns the exit status (2 for usage errors, printed as one line on stderr)."""
    verbose = False
    try:
        args = build_parser().parse_args(argv)
        verbose = args.verbose
        if not 1 <= args.threads <= 1024:
            raise UsageError(f"--threads must be >= 1 and <= 1024, got {args.threads}")
        _configure(args.verbose, args.threads, quiet=getattr(args, "quiet", False))
        return int(args.func(args))
    except UsageError as err:
        print(f"pal: error: {err}" if not str(err).startswith("pal") else f"{err}", file=sys.stderr)
        return 2
    except (ValueError, OSError) as err:  # bad input found while running (e.g. a body's names)
        if verbose:
            raise
        print(f"pal: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
