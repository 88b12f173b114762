"""Best known objective values of standard instances, for the gap-to-best-known column.

Keyed by the TSPLIB instance name and the number of units, as ``bench --tsplib FILE --units M``
builds them (depot node 1, every unit starting and ending there, 1 m/s so seconds = metres):
``total`` is the min-sum tour length, ``makespan`` the min-max (longest tour). Add a value only
with its source in a comment.
"""

from __future__ import annotations

#: (instance, units) -> objective -> best known value.
BEST_KNOWN: dict[tuple[str, int], dict[str, float]] = {
    # berlin52 multiple-TSP, LKH-3 best published values with integer-rounded (TSPLIB EUC_2D)
    # distances, as used by benchmarks/planning.py (Helsgaun, LKH-3 mTSP instances). Our
    # distances are real-valued, so a plan may come out slightly below these (gap < 0).
    ("berlin52", 3): {"total": 7735.0, "makespan": 3070.0},
    ("berlin52", 5): {"total": 8124.0, "makespan": 2440.0},
}


def best_known(instance: str, units: int) -> dict[str, float] | None:
    """The best known values of ``instance`` with ``units`` units, if the table has them."""
    return BEST_KNOWN.get((instance, units))
