"""Figures in the Markdown tables of experiments and benchmark scripts, formatted one way."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np


def mean_std(values: Iterable[float | None], digits: int = 1, unit: str = "") -> str:
    """``mean ± std`` (population std) of the finite ones among ``values``, with how many when
    some runs did not measure it ("0.12 ± 0.03 (4 of 5)"); "—" when none did."""
    all_ = list(values)
    finite = [float(v) for v in all_ if v is not None and np.isfinite(v)]
    if not finite:
        return "—"
    text = f"{np.mean(finite):.{digits}f} ± {np.std(finite):.{digits}f}{unit}"
    return text if len(finite) == len(all_) else f"{text} ({len(finite)} of {len(all_)})"
