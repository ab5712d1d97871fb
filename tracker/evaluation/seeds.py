"""Simulator seeds and the held-out discipline (issue 11).

Tuning uses simulator seeds 0–4 only (:data:`TUNING_SEEDS`); figures that are reported (BENCHMARKS.md, issues)
come from seeds ≥ :data:`HELDOUT_MIN` only, which nobody tunes on. ``--seeds`` arguments are parsed by
:func:`parse_seeds` (``"100-109"``, ``"100,105"``, ``"100-103,120"``); :func:`check_seeds` refuses a list that
mixes the two sets or uses seeds of neither.
"""

from __future__ import annotations

TUNING_SEEDS = range(0, 5)
"""Seeds for tuning (development runs); never reported."""
HELDOUT_MIN = 100
"""Smallest seed whose figures may be reported."""


def parse_seeds(text: str) -> list[int]:
    """``"100-103,120"`` → ``[100, 101, 102, 103, 120]`` (order kept, duplicates dropped); ``ValueError`` with the
    offending item otherwise."""
    seeds: list[int] = []
    for item in str(text).split(","):
        item = item.strip()
        if not item:
            continue
        lo, sep, hi = item.partition("-")
        try:
            a = int(lo)
            b = int(hi) if sep else a
        except ValueError:
            raise ValueError(f"seeds: {item!r} is not a seed or a range A-B of seeds (e.g. 100-109 or 100,105)"
                             ) from None
        if a < 0 or b < a:
            raise ValueError(f"seeds: {item!r} is not a non-empty range of non-negative seeds")
        for s in range(a, b + 1):
            if s not in seeds:
                seeds.append(s)
    if not seeds:
        raise ValueError(f"seeds: {text!r} names no seed")
    return seeds


def check_seeds(seeds: list[int], dev: bool = False) -> list[int]:
    """Return ``seeds`` when they fit the purpose, else raise ``ValueError`` saying why.

    ``dev`` False (reporting): every seed ≥ ``HELDOUT_MIN`` (seeds 0–4 are for tuning, 5–99 are neither).
    ``dev`` True (tuning): every seed in ``TUNING_SEEDS``.
    """
    if dev:
        bad = [s for s in seeds if s not in TUNING_SEEDS]
        if bad:
            raise ValueError(f"seeds {bad}: development (tuning) runs use seeds {TUNING_SEEDS.start}–"
                             f"{TUNING_SEEDS.stop - 1} only")
        return seeds
    tuning = [s for s in seeds if s in TUNING_SEEDS]
    if tuning:
        raise ValueError(f"seeds {tuning} are tuning seeds ({TUNING_SEEDS.start}–{TUNING_SEEDS.stop - 1}): their "
                         f"figures are never reported; use seeds ≥ {HELDOUT_MIN}, or a development run")
    low = [s for s in seeds if s < HELDOUT_MIN]
    if low:
        raise ValueError(f"seeds {low}: reported figures come from held-out seeds ≥ {HELDOUT_MIN} only")
    return seeds
