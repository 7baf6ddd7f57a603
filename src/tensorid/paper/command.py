"""`tensorid paper`: the paper study from the command line."""

from __future__ import annotations

from pathlib import Path

from ..analysis.summary import Table, as_text


def _paper(args) -> int:
    from rich.console import Console

    from ..app.output import check_destination
    from .study import run

    check_destination(args.out)
    starts = args.starts if args.starts is not None else (6 if args.quick else 100)
    if starts < 1:
        raise ValueError(f"--starts must be at least 1, got {starts}")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be at least 1, got {args.workers}")
    if args.levels:
        from .study import level_options

        for level in args.levels:
            try:
                level_options(level)
            except ValueError as e:
                raise ValueError(f"--levels: {e}") from None
    res = run(
        Path(args.out),
        starts=starts,
        quick=args.quick,
        workers=args.workers,
        seed=args.seed,
        progress=not args.no_progress,
        levels=args.levels,
    )
    sb, tt = res["silverbox"], res["two_tank"]
    c = Console(highlight=False, soft_wrap=True)  # whole lines in a log too
    c.print(
        f"[bold]Silverbox[/] paper's model: training cost "
        f"{sb['paper_model']['train_cost']:.5g}, validation GOF "
        f"{sb['paper_model']['val_gof']:.4f}; with input offset: validation GOF "
        f"{sb['offset_model']['val_gof']:.4f}"
    )
    c.print(f"[bold]Two-tank[/] GOF {tt['paper_model']['gof']:.4f}")
    rtol = res["meta"]["converged_rtol"]
    print(as_text([_robustness_table(res["robustness"], rtol)]), end="")
    c.print(
        f"Wrote {args.out}/results.json, report.md and figures in {res['meta']['seconds']:.0f} s"
    )
    return 0


def _robustness_table(rows: list[dict], rtol: float) -> Table:
    """The robustness comparison as report.md has it (fewer columns): one row per data
    set, accuracy level and method, its columns named."""
    header = ["dataset", "accuracy", "method", "converged", "reported failure"]
    body = [
        [r["dataset"], r["accuracy"], r["method"], f"{r['converged']}/{r['starts']}",
         str(r["failed"]), f"{r['median_seconds'] * 1e3:.1f}"]
        for r in rows
    ]  # fmt: skip
    title = (
        f"robustness: starts that converged (cost within {rtol:g} of the best found), and "
        "those whose optimizer reported failure (not the opposite: BFGS often reaches the "
        "optimum and then fails its line search); report.md has the rest"
    )
    return Table(title, [*header, "median ms"], body)


# the quick study's time, said the same in README.md and docs/index.md (a test checks):
# measured from a fresh clone, with an empty compilation cache and then a warm one
QUICK_SECONDS = {
    "empty cache": 27,
    "warm cache": 11,
    "measured": "measured 2026-12-06 on 2 cores, idle",
}


def register(sub) -> None:
    """Add the paper command to the subparsers ``sub``."""
    p = sub.add_parser(
        "paper",
        help="reproduce the paper's Silverbox and two-tank studies",
        description="Run the paper's identification problems and robustness "
        "comparison on the bundled data; write results.json, "
        "report.md and figures.",
    )
    p.add_argument("--out", default="paper-results", help="output folder (default: %(default)s)")
    p.add_argument(
        "--starts",
        type=int,
        default=None,
        help="initial guesses per method and accuracy level (default 100; 6 with --quick)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="small version: one accuracy level and few starts (about "
        f"{QUICK_SECONDS['empty cache']} s, {QUICK_SECONDS['warm cache']} s once the compiled "
        f"code is cached: {QUICK_SECONDS['measured']})",
    )
    p.add_argument(
        "--levels",
        nargs="+",
        default=None,
        metavar="LEVEL",
        help="accuracy levels of the robustness study: rk4xN (RK4, N substeps per sample) "
        "or dopri5-TOL (adaptive, rtol = atol = TOL); default rk4x4 rk4x16 rk4x64 "
        "dopri5-1e-10 dopri5-1e-12 dopri5-1e-14 (rk4x4 with --quick)",
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
