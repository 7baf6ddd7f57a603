"""A fit's counters (``FitResult.stats``): iterations, evaluations, Hessian-vector
products, for one start and for all."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace


@dataclass(frozen=True)
class Stats(Mapping):
    """A fit's counters, read-only: a mapping (``res.stats["nit"]``) and attributes.

    nit, nfev, nhev : iterations, cost evaluations, Hessian-vector products.
    nit_total, nfev_best : with several starts, every start's iterations and the best
        start's evaluations (for one start, nit and nfev: the default).
    """

    nit: int = 0
    nfev: int = 0
    nhev: int = 0
    nit_total: int | None = None
    nfev_best: int | None = None

    def __post_init__(self) -> None:
        default = {"nit_total": self.nit, "nfev_best": self.nfev}
        for k in self:
            v = getattr(self, k)
            object.__setattr__(self, k, int(default[k] if v is None else v))

    def __getitem__(self, key: str) -> int:
        if key not in self.__dataclass_fields__:
            raise KeyError(key)
        return getattr(self, key)

    def __iter__(self):
        return iter(self.__dataclass_fields__)

    def __len__(self) -> int:
        return len(self.__dataclass_fields__)

    def then(self, later: Stats) -> Stats:
        """The counts of this run followed by ``later`` (a refit, a polish): summed."""
        return Stats(**{k: self[k] + later[k] for k in self})

    def plus(self, **more: int) -> Stats:
        """These counts with ``more`` added to the ones named."""
        return replace(self, **{k: self[k] + int(v) for k, v in more.items()})
