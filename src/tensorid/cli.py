"""Command line: tensorid paper | ..."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _paper(args) -> int:
    from rich.console import Console

    from . import paper

    starts = args.starts if args.starts is not None else (6 if args.quick else 100)
    if starts < 1:
        raise SystemExit("--starts must be at least 1")
    res = paper.run(
        Path(args.out),
        starts=starts,
        quick=args.quick,
        workers=args.workers,
        seed=args.seed,
        progress=not args.no_progress,
    )
    sb, tt = res["silverbox"], res["two_tank"]
    c = Console()
    c.print(
        f"[bold]Silverbox[/] paper's model: training cost "
        f"{sb['paper_model']['train_cost']:.5g}, validation GOF "
        f"{sb['paper_model']['val_gof']:.4f}; with input offset: validation GOF "
        f"{sb['offset_model']['val_gof']:.4f}"
    )
    c.print(f"[bold]Two-tank[/] GOF {tt['paper_model']['gof']:.4f}")
    for row in res["robustness"]:
        c.print(
            f"  {row['dataset']:9s} {row['accuracy']:7s} {row['method']:12s} converged "
            f"{row['converged']:3d}/{row['starts']}  failed {row['failed']:3d}  "
            f"median {row['median_seconds'] * 1e3:7.1f} ms"
        )
    c.print(
        f"Wrote {args.out}/results.json, report.md and figures in {res['meta']['seconds']:.0f} s"
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="tensorid",
        description="Grey-box system identification with exact gradients and Hessians "
        "from state/parameter transition tensors.",
    )
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser(
        "paper",
        help="reproduce the paper's Silverbox and two-tank studies",
        description="Run the paper's identification problems and robustness "
        "comparison on the bundled data; write results.json, "
        "report.md and figures.",
    )
    p.add_argument("--out", default="paper-results", help="output folder")
    p.add_argument(
        "--starts",
        type=int,
        default=None,
        help="initial guesses per method and accuracy level (default 100; 6 with --quick)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="small version: one accuracy level and few starts (about a minute)",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help="worker processes for the starts (default: all cores)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the random starts")
    p.add_argument("--no-progress", action="store_true", help="no live progress display")
    p.set_defaults(func=_paper)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
