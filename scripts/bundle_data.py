"""Regenerate the compact records in src/tensorid/datasets/ from ../shared/data.

    python scripts/bundle_data.py [path/to/shared/data]

Checks the SHA-256 of each source file against its PROVENANCE.md before copying.
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np
import scipy.io

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "src" / "tensorid" / "datasets"
SOURCES = {
    "silverbox/Schroeder80mV.mat": (
        "ec5a9740a4789aa20b9d84f387424c0218e843844807b30b367c218778339fb6"
    ),
    "silverbox/SNLS80mV.mat": ("5c7413a52255af0cb4e2f93fb6903beb92b08965ba1e6ad0a6ffedfed8477ed4"),
    "two_tank/tank.mat": "def34c70b239f7d5e9e2228e957a6dfdbb909340941db8f84b23686a17fd3133",
    "emps/DATA_EMPS.mat": "6cf6814ae14618795da0101aae2bb97ff0c6351b0501b5492751b02b07facf7e",
    "emps/DATA_EMPS_PULSES.mat": (
        "0eab75bb1f6b16228ee78791343a88bf9bfd9a51036ac9807d7b5fc11c0e1704"
    ),
    "theophylline/Theoph.csv": ("973dbf641d86ce6fc298077267fa1f64f4993a8abbeab09719d737a612fa2f54"),
}
SILVERBOX_START, SILVERBOX_STOP = 10000, 14000  # holds the paper's [10584:13655]


def main(shared: Path) -> None:
    for rel, sha in SOURCES.items():
        digest = hashlib.sha256((shared / rel).read_bytes()).hexdigest()
        if digest != sha:
            raise SystemExit(f"{rel}: sha256 {digest} does not match PROVENANCE.md ({sha})")
    sb = scipy.io.loadmat(shared / "silverbox/Schroeder80mV.mat")
    V1, V2 = sb["V1"].ravel(), sb["V2"].ravel()
    np.savez_compressed(
        OUT / "silverbox_schroeder80mV.npz",
        V1=V1[SILVERBOX_START:SILVERBOX_STOP],
        V2=V2[SILVERBOX_START:SILVERBOX_STOP],
        start=SILVERBOX_START,
        record_length=V1.size,
        record_mean_V1=V1.mean(),
        record_mean_V2=V2.mean(),
    )
    # the whole 131,072-sample record, for long-record fits and memory benchmarks
    snls = scipy.io.loadmat(shared / "silverbox/SNLS80mV.mat")
    np.savez_compressed(
        OUT / "silverbox_snls80mV.npz", V1=snls["V1"].ravel(), V2=snls["V2"].ravel()
    )
    tank = scipy.io.loadmat(shared / "two_tank/tank.mat")
    np.savez_compressed(OUT / "two_tank.npz", u=tank["u"].ravel(), y=tank["y"])
    # both EMPS records, float64 as measured; t is k·1 ms within 3.2e-8 s, so not kept
    emps = {}
    for record, name in (("estimation", "DATA_EMPS"), ("test", "DATA_EMPS_PULSES")):
        m = scipy.io.loadmat(shared / f"emps/{name}.mat")
        emps |= {f"{record}_{k}": m[k].ravel() for k in ("vir", "qm", "qg")}
        emps |= {k: float(m[k].item()) for k in ("kp", "kv", "gtau")}
    emps["test_pulses"] = m["pulses_N"].ravel()
    np.savez_compressed(OUT / "emps.npz", **emps)
    # 3 kB of text: copied as it is (the same SHA-256), read by --records ID
    (OUT / "theophylline.csv").write_bytes((shared / "theophylline/Theoph.csv").read_bytes())
    for f in sorted(OUT.glob("*.npz")):
        print(f.name, f.stat().st_size, "bytes")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT.parent / "shared" / "data")
