"""report.md for the paper study: every number and every comparison in it comes from
the run's own results, so the text stays true when the numbers change."""

from __future__ import annotations

import numpy as np

from ..app.reports import md_table


def _f(v, d=4):
    return "–" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.{d}g}"


def render(r: dict, figures: list[str]) -> str:
    meta = r["meta"]
    out = [
        "# Reproducing Saha & Singh with tensorid",
        "",
        f"tensorid {meta['tensorid']}, {meta['date'][:19]} UTC, {meta['machine']}; "
        f"the whole run took {meta['seconds']:.0f} s "
        f"({'quick version' if meta['quick'] else 'full study'}, {meta['starts']} starts per "
        f"method and accuracy level). Every number below is from this run (results.json).",
        "",
        "## Silverbox",
        "",
        "Model m ÿ + d ẏ + (a + b y²) y = u, states (y, ẏ), θ = (ẏ(t0), m, d, a, b), "
        "y(t0) the first measured sample; trained on Schroeder80mV samples [10584:11608], "
        "validated on [11608:13655] from y(t0) measured and ẏ(t0) = 0, as in the paper. "
        "Fitted by trust-region Newton with the exact Hessian from transition tensors, "
        "RK4 with 4 substeps per sample, from the paper's initial guess.",
        "",
    ]
    out += _silverbox_table(r["silverbox"]) + _silverbox_why(r["silverbox"])
    out += _two_tank(r["two_tank"])
    out += ["", "## Robustness: the paper's Table 1", ""]
    out += _robustness(r) + _robustness_verdict(r["robustness"])
    return "\n".join(out) + "\n"


def _silverbox_table(sb: dict) -> list[str]:
    pm, pe, om = sb["paper_model"], sb["paper_estimates"], sb["offset_model"]
    rows = []
    for name in ("m", "d", "a", "b", "u0"):
        rows.append(
            [
                name,
                _f(pm["params"].get(name), 6),
                _f(pe["params"].get(name), 6),
                _f(om["params"].get(name), 6),
            ]
        )
    rows += [
        ["ẏ(t0)", _f(pm["x0"][1], 6), _f(pe["x0"][1], 6), _f(om["x0"][1], 6)],
        [
            "y(t0)",
            _f(pm["x0"][0], 6) + " (measured)",
            _f(pe["x0"][0], 6),
            _f(om["x0"][0], 6) + " (estimated)",
        ],
        [
            "training cost J",
            _f(pm["train_cost"], 6),
            _f(pe["train_cost"], 6),
            _f(om["train_cost"], 6),
        ],
        ["training GOF", _f(pm["train_gof"], 5), _f(pe["train_gof"], 5), _f(om["train_gof"], 5)],
        [
            "validation GOF",
            _f(pm["val_gof"], 5),
            f"{_f(pe['val_gof'], 5)} (paper reports {pe['reported_val_gof']:.5f})",
            _f(om["val_gof"], 5),
        ],
        ["iterations", pm["iterations"], "27 (paper)", om["iterations"]],
    ]
    out = [
        md_table(
            [
                "",
                "paper's model, our fit",
                "paper's estimates, our simulator",
                "with input offset u0 (beyond the paper)",
            ],
            rows,
        ),
        "",
    ]
    return out


def _silverbox_why(sb: dict) -> list[str]:
    pm, pe, om, mr = (
        sb["paper_model"],
        sb["paper_estimates"],
        sb["offset_model"],
        sb["mean_removed"],
    )
    cheaper = pm["train_cost"] <= pe["train_cost"]
    return [
        "![training](silverbox_train.png)",
        "",
        "![validation](silverbox_validation.png)",
        "",
        "![offset validation](silverbox_offset_validation.png)",
        "",
        "### Why the validation GOF differs from the paper's 0.9626",
        "",
        f"- On the raw records our fit of the paper's model has a training cost of "
        f"{pm['train_cost']:.5g}, {'below' if cheaper else 'above'} the "
        f"{pe['train_cost']:.5g} of the paper's own estimates evaluated on the same "
        f"simulator, and a validation GOF of {pm['val_gof']:.4f}; the paper's estimates "
        f"reach {pe['val_gof']:.4f} there, not the reported {pe['reported_val_gof']:.4f}. "
        "So on raw data neither parameter set gives the paper's figure.",
        f"- The benchmark archive's README tells users to remove the means of V1 and V2 "
        f"(the input carries a ≈ +6.2 mV offset). With the record means removed, the "
        f"paper's estimates give a validation GOF of {mr['paper_estimates_val_gof']:.4f}, "
        f"close to the reported {pe['reported_val_gof']:.4f}, and our refit gives "
        f"{mr['val_gof']:.4f} (training cost {mr['train_cost']:.4g}). The paper most "
        "likely worked on mean-removed data; the remaining gap to its number is of the size "
        "that the rounding of its printed estimates (4 significant digits) and a different "
        "ODE solver produce.",
        f"- The offset variant needs no preprocessing: it estimates the offset from the raw "
        f"data as u0 = {om['params']['u0'] * 1e3:.3f} mV (with y(t0) free) and reaches a "
        f"validation GOF of {om['val_gof']:.4f}, with a training cost "
        f"{pm['train_cost'] / om['train_cost']:.0f}× lower than the paper's model.",
        "",
    ]


def _two_tank(tt: dict) -> list[str]:
    tpm, tpe, tz = tt["paper_model"], tt["paper_estimates"], tt["zoh_input"]
    rows = [
        [n, _f(tpm["params"][n], 5), _f(tpe["params"][n], 5), _f(tz["params"][n], 5)]
        for n in ("p1", "p2", "p3", "p4")
    ]
    rows += [
        ["cost J", _f(tpm["cost"], 6), _f(tpe["cost"], 6), _f(tz["cost"], 6)],
        [
            "GOF",
            _f(tpm["gof"], 5),
            f"{_f(tpe['gof'], 5)} (paper reports {tpe['reported_gof']:.5f})",
            _f(tz["gof"], 5),
        ],
        ["iterations", tpm["iterations"], "100 (paper)", "–"],
    ]
    out = [
        "## Two-tank",
        "",
        "Model x1' = -p1 √x1 + p2 u, x2' = -p3 √x2 + p4 √x1, y = x2, on the first 501 "
        "samples (Ts = 5 s) with both initial levels measured; √ is `safe_sqrt`, equal to "
        "√ above 1e-6 and smooth below. Newton from the paper's guess (0.04, 0.02, 0.02, 0.04).",
        "",
        md_table(
            [
                "",
                "paper's model, our fit (linear input)",
                "paper's estimates, our simulator",
                "our fit, zero-order-hold input",
            ],
            rows,
        ),
        "",
        "![two-tank](two_tank.png)",
        "",
        "### Why the numbers differ from the paper's",
        "",
        f"- Our fit reaches GOF {tpm['gof']:.4f} against the paper's {tpe['reported_gof']:.5f}; "
        f"the paper's printed estimates give only {tpe['gof']:.4f} on our simulator, with a "
        f"cost {tpe['cost'] / tpm['cost']:.2f}× ours. The estimates differ mostly in p1, p2 "
        "and p4, which trade off against each other along a shallow valley (the upper tank "
        "is not measured in the cost), so printed 3-digit values of a different solver's "
        "optimum need not score well on ours.",
        f"- The pump input is piecewise constant; holding it between samples (zero-order "
        f"hold) gives GOF {tz['gof']:.4f}, linear interpolation {tpm['gof']:.4f}. Both are "
        "reported; the default is linear, as MATLAB's idnlgrey interpolates.",
        f"- Lowest simulated levels of the fit: x1 {tpm['min_levels'][0]:.3g}, "
        f"x2 {tpm['min_levels'][1]:.3g} (the upper tank almost empties).",
    ]
    for w in tpm["warnings"] + tpe["warnings"]:
        out.append(f"- **Warning:** {w}")
    return out


def _robustness(r: dict) -> list[str]:
    meta, rows = r["meta"], r["robustness"]
    err = meta["integration_error"]
    out = [
        f"{meta['starts']} initial guesses per data set, drawn uniformly within ±20 % of the "
        f"paper's guess (seed {meta['seed']}; ẏ(t0) = 0 stays 0), the same starts for every "
        f"method and accuracy level, run on {meta['workers']} worker processes. A start "
        f"*converged* when its cost is within {meta['converged_rtol']:g} (relative) of the "
        "best cost any method found at that level; it *failed* when the optimizer itself "
        "reported failure or the result is not finite (a start can have converged and "
        "failed: BFGS often reaches the optimum and then reports a line-search failure). "
        "Validation GOF is on the validation window for Silverbox and on the fitted record "
        "for the two-tank (the paper has no separate validation set there). Seconds exclude "
        "compilation. *multiple-shooting*, not in the paper, is exact Newton on the record "
        f"cut into {meta.get('segments', 5)} segments (continuity as constraints, exact "
        "Lagrangian Hessian), then a single-shooting polish: its iterations count both.",
        "",
    ]
    header = [
        "data set",
        "accuracy",
        "method",
        "converged",
        "reported failure",
        "best val GOF",
        "median val GOF",
        "median iterations",
        "median cost evaluations",
        "median seconds",
    ]
    table = [
        [
            x["dataset"],
            x["accuracy"],
            x["method"],
            f"{x['converged']}/{x['starts']}",
            x["failed"],
            _f(x["best_val_gof"], 5),
            _f(x["median_val_gof"], 5),
            _f(x["median_iterations"], 3),
            _f(x["median_nfev"], 4),
            _f(x["median_seconds"], 3),
        ]
        for x in rows
    ]
    out += [md_table(header, table), "", "![robustness](robustness.png)", ""]
    levels = sorted({x["accuracy"] for x in rows}, key=lambda a: _level_key(a))
    adaptive = [lv for lv in levels if lv.startswith("dopri5")]
    out += [
        "Accuracy levels: the paper varies the tolerances of MATLAB's adaptive ODE solver "
        "(1e-10, 1e-12, 1e-14). The rk4xN levels are tensorid's fixed-step RK4 with N "
        "substeps per sample; the dopri5-TOL levels are the adaptive Dormand-Prince "
        "scheme at rtol = atol = TOL (rtol raised to 100 machine epsilons, 2.2e-14, at "
        "1e-14, as MATLAB's ode45 raises it), the paper's own levels, where step-size control "
        "reacts to every change of θ (finite-difference perturbations included, as in "
        "MATLAB), while tensorid's derivatives stay those of the adaptive discretisation "
        "actually taken. Their measured output error (max |y − y_ref| / max |y_ref| at the "
        "paper's estimates, against RK4 with 2048 substeps) is:",
        "",
        md_table(["problem"] + levels, [[d] + [_f(err[d][lv], 2) for lv in levels] for d in err]),
        "",
        "A fixed-step scheme makes the simulated cost a smooth function of θ at every "
        "level, so finite differences are not corrupted by step-size changes there: on "
        "the rk4 rows the baselines are stronger than the paper's MATLAB runs, and the "
        "table measures the optimizers on one and the same simulator.",
        "",
    ]
    if adaptive:
        out += _against_the_paper(rows, adaptive) + [""]
    else:
        out += ["The adaptive levels (dopri5-TOL) were not run here (the quick study).", ""]
    return out


# the paper's Table 1 (Silverbox only): best validation GOF at each tolerance, by its
# method and by MATLAB's finite-difference grey-box toolbox, which could start from
# none of 100 starts at 1e-14 (aborted), from 3 of 100 at 1e-12 and from all at 1e-10
PAPER_TABLE_1 = {
    "1e-14": ("96.527 %", "aborted (0/100 started)"),
    "1e-12": ("96.258 %", "55.627 % (3/100 started)"),
    "1e-10": ("96.251 %", "76.782 % (100/100 started)"),
}


def _level_key(level: str) -> tuple:
    if level.startswith("rk4x"):
        return (0, int(level[4:]))
    return (1, -float(level.split("-", 1)[1]))


def _against_the_paper(rows: list[dict], adaptive: list[str]) -> list[str]:
    """The Silverbox adaptive rows beside the paper's Table 1, whatever they show."""
    methods = list(dict.fromkeys(x["method"] for x in rows))
    header = ["tolerance", "paper: its method", "paper: MATLAB grey-box"] + methods
    table = []
    for lv in adaptive:
        tol = lv.split("-", 1)[1]
        cells = [tol, *PAPER_TABLE_1.get(tol, ("", ""))]
        for m in methods:
            x = next((r for r in rows if (r["dataset"], r["accuracy"], r["method"])
                      == ("silverbox", lv, m)), None)  # fmt: skip
            gof = f"{100 * x['best_val_gof']:.3f} %" if x else ""
            cells.append(f"{gof} ({x['converged']}/{x['starts']})" if x else "")
        table.append(cells)
    return [
        "Beside the paper's Table 1 (Silverbox; best validation GOF at each tolerance): "
        "here, the best validation GOF of each method, and in brackets the starts that "
        "reached the best cost. The paper's GOF is on its own validation window "
        "convention; the rk4 rows above show how the same model scores here (see the "
        "headline numbers), so compare the columns of one table, not across them. For "
        "the two-tank problem the paper reports that every tolerance worked (GOF 0.79088).",
        "",
        md_table(header, table),
    ]


def _robustness_verdict(rows: list[dict]) -> list[str]:
    """One sentence per method: how often it reached the best cost."""
    out = []
    newton = [x for x in rows if x["method"] == "newton"]
    if newton:
        worst = min(newton, key=lambda x: x["converged"] / x["starts"])
        if worst["converged"] == worst["starts"]:
            out.append(
                "Newton with the exact Hessian reached the best cost from every start in every row."
            )
        else:
            out.append(
                f"Newton with the exact Hessian reached the best cost from at least "
                f"{worst['converged']}/{worst['starts']} starts in every row "
                f"(lowest: {worst['dataset']}, {worst['accuracy']})."
            )
    for m in ("gauss-newton", "fd-lsq", "fd-bfgs", "multiple-shooting", "auto"):
        ms = [x for x in rows if x["method"] == m]
        if ms:
            conv = sum(x["converged"] for x in ms)
            tot = sum(x["starts"] for x in ms)
            fails = sum(x["failed"] for x in ms)
            out.append(
                f"{m}: converged in {conv}/{tot} runs over all rows; the optimizer "
                f"reported failure in {fails}."
            )
    return out
