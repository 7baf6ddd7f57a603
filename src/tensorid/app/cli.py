"""Command line: tensorid paper | ..."""

from __future__ import annotations

import argparse
import os
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


def _fit(args) -> int:
    from .fitcli import run_fit

    return run_fit(args)


def _simulate(args) -> int:
    from .fitcli import run_simulate

    return run_simulate(args)


def _samples(text: str) -> tuple[int, int]:
    try:
        a, b = text.split(":")
        return int(a), int(b)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected START:STOP sample indices, got {text!r}"
        ) from None


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

    f = sub.add_parser(
        "fit",
        help="fit a model file to data files",
        description="Estimate the unknown parameters and initial states of "
        "MODEL.py from DATA files; write fit.json, report.md and "
        "figures to --out.",
    )
    f.add_argument("model", help="model file (Python)")
    f.add_argument("data", nargs="+", help="data files (.csv, .mat, .npz), one experiment each")
    f.add_argument("--out", default="fit-results", help="output folder")
    f.add_argument(
        "--method",
        default="newton",
        # tensorid.METHODS, spelled out so that --help need not import JAX
        choices=["newton", "newton-cg", "gauss-newton", "fd-bfgs", "fd-lsq"],
        help="newton: exact Hessian (default); newton-cg: exact Hessian-vector products "
        "with truncated CG, for many unknowns; gauss-newton; fd-bfgs and fd-lsq: "
        "finite-difference baselines",
    )
    f.add_argument(
        "--validate", nargs="*", default=[], metavar="DATA", help="validation data files"
    )
    f.add_argument(
        "--ts", type=float, default=None, help="sampling time, for data files without a 't' column"
    )
    f.add_argument(
        "--samples",
        type=_samples,
        default=None,
        metavar="START:STOP",
        help="use samples START:STOP of each training file",
    )
    f.add_argument(
        "--validate-samples",
        type=_samples,
        default=None,
        metavar="START:STOP",
        help="use samples START:STOP of each validation file",
    )
    f.add_argument("--starts", type=int, default=1, help="number of starts (multi-start)")
    f.add_argument(
        "--spread",
        type=float,
        default=0.2,
        help="relative spread of the starts around p0 where no bounds are given",
    )
    f.add_argument("--seed", type=int, default=0, help="seed of the starts")
    f.add_argument("--workers", type=int, default=None, help="local worker processes")
    f.add_argument(
        "--batch",
        type=int,
        default=None,
        help="starts fitted together in lock-step per task, vectorised (newton, "
        "gauss-newton; default: the starts shared evenly over the local workers)",
    )
    f.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run the starts on a Dask distributed cluster at ADDRESS",
    )
    _integration_options(f)
    f.add_argument("--no-progress", action="store_true", help="no live progress display")
    f.set_defaults(func=_fit)

    s = sub.add_parser(
        "simulate",
        help="simulate a model file for given parameters",
        description="Simulate MODEL.py on the inputs of DATA with the given "
        "parameters; write simulation.csv (and GOF when DATA "
        "has outputs).",
    )
    s.add_argument("model")
    s.add_argument("data")
    s.add_argument(
        "--params",
        nargs="*",
        default=[],
        metavar="NAME=VALUE",
        help="parameter values (default: p0 of the model file), or a fit.json",
    )
    s.add_argument("--x0", nargs="*", default=[], metavar="STATE=VALUE")
    s.add_argument("--ts", type=float, default=None)
    _integration_options(s)
    s.add_argument("--out", default="simulation.csv")
    s.set_defaults(func=_simulate)
    return ap


def _integration_options(p: argparse.ArgumentParser) -> None:
    from .integrate import SCHEMES

    p.add_argument(
        "--scheme",
        default="rk4",
        choices=list(SCHEMES),
        help="integrator: explicit rk4 (default), rk38, heun, euler; implicit sdirk3, "
        "sdirk2, implicit-euler for stiff models; adaptive dopri5, bosh3 (with --rtol/--atol)",
    )
    p.add_argument("--substeps", type=int, default=4, help="steps per sample interval")
    p.add_argument("--rtol", type=float, default=None, help="adaptive schemes: relative tolerance")
    p.add_argument("--atol", type=float, default=None, help="adaptive schemes: absolute tolerance")
    p.add_argument("--interpolation", default="linear", choices=["linear", "zoh"])


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from ._config import enable_compilation_cache

    enable_compilation_cache()
    try:
        return args.func(args)
    except (ValueError, TypeError, FileNotFoundError) as e:
        # our errors say what is wrong and how to fix it; a traceback only hides that
        # (set TENSORID_TRACEBACK=1 to see it anyway)
        if os.environ.get("TENSORID_TRACEBACK"):
            raise
        print(f"tensorid: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
