"""Statistics for bench results: repeats summarised, and two result sets compared in pairs.

Pure Python and numpy (scipy is not a dependency): the 95 % confidence interval of a mean uses
Student's t from a table, and the paired tests are the sign test (exact binomial) and the
Wilcoxon signed-rank test (exact distribution for up to 25 pairs without ties, else the normal
approximation with the tie correction).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

#: Two-sided 95 % quantiles of Student's t by degrees of freedom (standard tables).
_T95: dict[int, float] = {
    1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262,
    10: 2.228, 11: 2.201, 12: 2.179, 13: 2.160, 14: 2.145, 15: 2.131, 16: 2.120, 17: 2.110,
    18: 2.101, 19: 2.093, 20: 2.086, 21: 2.080, 22: 2.074, 23: 2.069, 24: 2.064, 25: 2.060,
    26: 2.056, 27: 2.052, 28: 2.048, 29: 2.045, 30: 2.042, 40: 2.021, 60: 2.000, 120: 1.980,
}


def t95(df: int) -> float:
    """Student's t for a two-sided 95 % interval; between table rows the next smaller df
    (a slightly wider, so conservative, interval); 1.960 beyond 120."""
    if df < 1:
        raise ValueError(f"degrees of freedom must be >= 1, not {df}")
    if df > 120:
        return 1.960
    return _T95[max(k for k in _T95 if k <= df)]


@dataclass(frozen=True, slots=True)
class Summary:
    """Mean, median, sample standard deviation and the mean's 95 % CI of some repeats (one
    value: no spread, no interval)."""

    n: int
    mean: float
    median: float
    std: float | None
    ci_low: float | None
    ci_high: float | None
    min: float
    max: float


def describe(values: Sequence[float]) -> Summary:
    if not values:
        raise ValueError("no values to describe")
    x = np.asarray(values, dtype=float)
    mean, median = float(x.mean()), float(np.median(x))
    if len(x) < 2:
        return Summary(1, mean, median, None, None, None, mean, mean)
    std = float(x.std(ddof=1))
    half = t95(len(x) - 1) * std / math.sqrt(len(x))
    return Summary(len(x), mean, median, std, mean - half, mean + half, float(x.min()),
                   float(x.max()))


def geomean(values: Sequence[float]) -> float | None:
    """The geometric mean of positive values (None when there are none)."""
    x = [v for v in values if v is not None and v > 0]
    if not x:
        return None
    return float(math.exp(sum(math.log(v) for v in x) / len(x)))


# --------------------------------------------------------------------------- paired tests


def sign_test(differences: Sequence[float]) -> float | None:
    """Two-sided exact sign test p-value (zero differences dropped; None with no pairs left)."""
    pos = sum(1 for d in differences if d > 0)
    neg = sum(1 for d in differences if d < 0)
    n = pos + neg
    if n == 0:
        return None
    k = min(pos, neg)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2.0**n
    return min(1.0, 2.0 * tail)


def _ranks(values: Sequence[float]) -> list[float]:
    """Ranks 1..n, ties given their average rank."""
    order = sorted(range(len(values)), key=lambda i: values[i])
    ranks = [0.0] * len(values)
    i = 0
    while i < len(order):
        j = i
        while j + 1 < len(order) and values[order[j + 1]] == values[order[i]]:
            j += 1
        for k in range(i, j + 1):
            ranks[order[k]] = (i + j) / 2.0 + 1.0
        i = j + 1
    return ranks


def wilcoxon(differences: Sequence[float], exact_up_to: int = 25) -> float | None:
    """Two-sided Wilcoxon signed-rank p-value of paired differences (zeros dropped, Wilcoxon's
    convention). Exact without ties for n <= ``exact_up_to``, else the normal approximation
    with the tie correction and a continuity correction. None with no non-zero difference."""
    d = [float(v) for v in differences if v != 0]
    n = len(d)
    if n == 0:
        return None
    ranks = _ranks([abs(v) for v in d])
    w_plus = sum(r for r, v in zip(ranks, d, strict=True) if v > 0)
    ties = len(set(abs(v) for v in d)) < n
    if n <= exact_up_to and not ties:
        # counts[s] = number of sign patterns whose positive ranks sum to s
        top = n * (n + 1) // 2
        counts = [1] + [0] * top
        for r in range(1, n + 1):
            for s in range(top, r - 1, -1):
                counts[s] += counts[s - r]
        w = round(min(w_plus, top - w_plus))
        p = 2.0 * sum(counts[: w + 1]) / 2.0**n
        return min(1.0, p)
    mean = n * (n + 1) / 4.0
    groups: dict[float, int] = {}
    for v in d:
        groups[abs(v)] = groups.get(abs(v), 0) + 1
    var = n * (n + 1) * (2 * n + 1) / 24.0 - sum(t**3 - t for t in groups.values()) / 48.0
    if var <= 0:
        return None
    z = (abs(w_plus - mean) - 0.5) / math.sqrt(var)
    return min(1.0, math.erfc(max(z, 0.0) / math.sqrt(2.0)))
