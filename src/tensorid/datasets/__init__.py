"""Measured benchmark records bundled with tensorid (see README.md beside this file for
their origin, checksums and terms). Everything works offline."""

from __future__ import annotations

from functools import cache
from importlib import resources

import numpy as np

from ..engine.modelling.data import Experiment

SILVERBOX_TS = 2**14 / 1e7  # s; fs = 10^7 / 2^14 ≈ 610.35 Hz
SILVERBOX_TRAIN = (10584, 11608)  # the paper's points 10585..11608 (1-based), one period
SILVERBOX_VALIDATION = (11608, 13655)
TWO_TANK_TS = 5.0  # s, inferred by reproducing the paper (see README.md)
EMPS_TS = 1e-3  # s
EMPS_INIT_WINDOW = 20  # samples: the benchmark's state-initialisation window on the test record
# the benchmark document's reference model (inverse-model least squares, IDIM-LS)
EMPS_IDIM_LS = {"M": 95.1089, "Fv": 203.5034, "Fc": 20.3935, "offset": -3.1648}


@cache
def _load(name: str) -> dict[str, np.ndarray]:
    with resources.files(__package__).joinpath(name).open("rb") as f:
        with np.load(f) as z:
            return {k: z[k] for k in z.files}


def silverbox(
    start: int = SILVERBOX_TRAIN[0], stop: int = SILVERBOX_TRAIN[1], name: str | None = None
) -> Experiment:
    """Silverbox Schroeder80mV samples [start:stop] (0-based indices into the 131,072-
    sample record; bundled: [10000:14000]). u = V1 (input voltage), y = V2 (output
    voltage), t = index · Ts. The default window is the paper's training period."""
    d = _load("silverbox_schroeder80mV.npz")
    first = int(d["start"])
    last = first + d["V1"].size
    if not first <= start < stop <= last:
        raise ValueError(
            f"the bundled Silverbox record holds samples [{first}:{last}]; got [{start}:{stop}]"
        )
    sl = slice(start - first, stop - first)
    return Experiment(
        np.arange(start, stop) * SILVERBOX_TS,
        d["V1"][sl],
        d["V2"][sl],
        name=name or f"silverbox[{start}:{stop}]",
    )


def silverbox_snls80mV(stop: int | None = None) -> Experiment:
    """The whole SNLS80mV record (131,072 samples, about 215 s), float64 as measured:
    u = V1, y = V2. Filtered Gaussian noise of linearly growing amplitude (samples
    0 to about 40,500), then ten random-phase odd multisines (to about 127,400),
    then zero input. ``stop`` keeps the first samples only."""
    d = _load("silverbox_snls80mV.npz")
    n = d["V1"].size if stop is None else int(stop)
    if not 2 <= n <= d["V1"].size:
        raise ValueError(f"the SNLS80mV record has {d['V1'].size} samples; got stop={stop}")
    return Experiment(
        np.arange(n) * SILVERBOX_TS, d["V1"][:n], d["V2"][:n], name=f"silverbox-snls80mV[:{n}]"
    )


def silverbox_train() -> Experiment:
    return silverbox(*SILVERBOX_TRAIN, name="silverbox-train")


def silverbox_validation() -> Experiment:
    return silverbox(*SILVERBOX_VALIDATION, name="silverbox-validation")


def two_tank(samples: int = 501) -> Experiment:
    """The two-tank record: u = pump input, y = level of the LOWER tank (row 0 of the
    original y, the paper's output x2). The first ``samples`` samples at Ts = 5 s
    (the paper uses 501)."""
    d = _load("two_tank.npz")
    if not 2 <= samples <= d["u"].size:
        raise ValueError(f"the two-tank record has {d['u'].size} samples; got {samples}")
    return Experiment(
        np.arange(samples) * TWO_TANK_TS, d["u"][:samples], d["y"][0, :samples], name="two-tank"
    )


def two_tank_levels(samples: int = 501) -> np.ndarray:
    """Both measured levels, shape (samples, 2): column 0 the upper tank x1 (row 1 of
    the original y), column 1 the lower tank x2."""
    d = _load("two_tank.npz")
    return np.stack([d["y"][1, :samples], d["y"][0, :samples]], axis=1)


def emps_record(record: str = "estimation") -> dict:
    """One EMPS record as arrays: ``t`` (k·1 ms), ``vir`` (controller output, the
    force on the load is gtau·vir), ``qm`` (motor position, m), ``qg`` (reference
    position, m), ``pulses`` (the force pulses added to vir, in vir's units; zero on
    the estimation record), and the constants ``kp``, ``kv`` and ``gtau``.
    ``record`` is "estimation" (DATA_EMPS) or "test" (DATA_EMPS_PULSES)."""
    if record not in ("estimation", "test"):
        raise ValueError(f'record must be "estimation" or "test", got {record!r}')
    d = _load("emps.npz")
    out = {k: d[f"{record}_{k}"].copy() for k in ("vir", "qm", "qg")}  # not the cache's
    n = out["qm"].size
    pulses = d["test_pulses"].astype(float) if record == "test" else np.zeros(n)
    return {
        "t": np.arange(n) * EMPS_TS,
        **out,
        "pulses": pulses,
        **{k: float(d[k]) for k in ("kp", "kv", "gtau")},
    }


def emps(record: str = "estimation", closed_loop: bool = False) -> Experiment:
    """The EMPS positioning system (24,841 samples at 1 ms), as the benchmark splits it:
    ``record`` "estimation" for fitting, "test" (with force pulses) for validation with
    a 20-sample initialisation window (``EMPS_INIT_WINDOW``).

    Open loop (default): u = vir, y = qm. Closed loop: u = (qg, pulses), y = qm, for a
    model that holds the controller (see ``examples/emps``)."""
    d = emps_record(record)
    u = np.stack([d["qg"], d["pulses"]], axis=1) if closed_loop else d["vir"]
    name = f"emps-{record}" + ("-closed-loop" if closed_loop else "")
    return Experiment(d["t"], u, d["qm"], name=name)


def theophylline_csv():
    """The path of the bundled theophylline data (R's ``Theoph``: 12 subjects, one
    oral dose, 11 samples each; columns Subject, Wt, Dose, Time, conc, ID), one long
    file for ``ti.load_data(path, model, records="ID", columns={"t": "Time", ...})``
    or ``tensorid fit ... --records ID``. See README.md beside it."""
    from pathlib import Path

    return Path(str(resources.files(__package__).joinpath("theophylline.csv")))


def phenobarbital_csv():
    """The path of the bundled phenobarbital data (R's ``nlme::Phenobarb``: 59 neonates,
    589 IV doses, 155 concentrations) in NONMEM's layout (ID, TIME, AMT, DV, EVID, MDV,
    CMT, WT, APGAR), for ``ti.load_data(path, model, records="ID", columns={"t":
    "TIME", "conc": "DV"})`` or ``tensorid fit ... --records ID``. See README.md beside
    it."""
    from pathlib import Path

    return Path(str(resources.files(__package__).joinpath("phenobarbital.csv")))
