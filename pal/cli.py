"""The ``pal`` command.

pal demo [--out DIR] [--quick]
pal bench NAME [--json] [--out DIR]
pal experiment NAME [--json] [--out DIR] [--quick]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

__all__ = ["main"]


def _configure(verbose: bool, threads: int) -> None:
    os.environ.setdefault("MPLBACKEND", "Agg")
    import torch

    # The models work on small tensors: one intra-op thread is faster, and OpenMP threads
    # slow down by orders of magnitude when another process holds the second core.
    torch.set_num_threads(threads)
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )


def _config_from_args(module: Any, args: argparse.Namespace) -> Any:
    config = module.Config()
    if getattr(args, "quick", False):
        if not hasattr(module.Config, "quick"):
            raise SystemExit(f"{module.__name__} has no --quick configuration")
        config = module.Config.quick()
    overrides = {}
    for item in getattr(args, "set", None) or []:
        key, sep, raw = item.partition("=")
        names = {f.name for f in fields(config)}
        if not sep or key not in names:
            raise SystemExit(f"--set {item!r}: expected KEY=VALUE with KEY one of {sorted(names)}")
        try:
            overrides[key] = json.loads(raw)
        except json.JSONDecodeError:
            overrides[key] = raw
    return replace(config, **overrides) if overrides else config


def _run_registered(kind: str, args: argparse.Namespace) -> int:
    from pal.experiments import load_module
    from pal.experiments.output import jsonable, write_outputs

    try:
        module = load_module(kind, args.name)
    except ValueError as err:
        raise SystemExit(str(err)) from None
    config = _config_from_args(module, args)
    start = time.perf_counter()
    result = module.run(config, progress_bar=not args.json and sys.stderr.isatty())
    elapsed = time.perf_counter() - start
    data = result.to_dict()
    if args.out:
        figures = result.figures() if hasattr(result, "figures") else {}
        paths = write_outputs(
            args.out, args.name, data, result.to_markdown(), figures, jsonable(vars(config))
        )
        logging.getLogger("pal").info("wrote %s", ", ".join(str(p) for p in paths.values()))
    if args.json:
        print(json.dumps(jsonable(data), indent=2, sort_keys=True))
    else:
        print(result.to_markdown())
        print(f"\n({kind} {args.name} took {elapsed:.1f} s)")
    return 0


def _demo(args: argparse.Namespace) -> int:
    from pal.experiments import demo

    config = demo.Config.quick() if args.quick else demo.Config()
    config = replace(config, out_dir=str(Path(args.out)))
    start = time.perf_counter()
    for line in demo.run(config, progress_bar=sys.stderr.isatty()):
        print(line, flush=True)
    print(f"\n(pal demo took {time.perf_counter() - start:.1f} s; figures in {args.out})")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pal", description="Causal perception-action learning toolkit.")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads (default 1)")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("demo", help="short end-to-end run: prints results, saves figures")
    p.add_argument("--out", default="pal-demo", help="directory for figures and JSON (default: pal-demo)")
    p.add_argument("--quick", action="store_true", help="smallest sizes (seconds)")
    p.set_defaults(func=_demo)

    for kind, help_text in (("bench", "run a benchmark"), ("experiment", "run an experiment")):
        p = sub.add_parser(kind, help=help_text)
        p.add_argument("name")
        p.add_argument("--json", action="store_true", help="print the result as JSON")
        p.add_argument("--out", default=None, help="directory for JSON, markdown and PNG figures")
        p.add_argument("--quick", action="store_true", help="small configuration")
        p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a config field")
        p.set_defaults(func=lambda a, k=kind: _run_registered(k, a))
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.threads < 1:
        raise SystemExit(f"--threads must be >= 1, got {args.threads}")
    _configure(args.verbose, args.threads)
    return int(args.func(args))


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
