"""Per-register statistics of the scan snapshots (pure): the values one register took, whether
it was readable, and runs of consecutive addresses.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from .scan_types import RegisterStats


def _value(v: int | None) -> int | None:
    return None if v is None else int(v)


def _present(values: Sequence[int | None]) -> bool:
    return any(v is not None for v in values)


def _stats(table: str, address: int, values: Sequence[int | None]) -> RegisterStats:
    seen = [v for v in values if v is not None]
    return RegisterStats(
        table=table,
        address=address,
        samples=len(seen),
        unreadable=len(values) - len(seen),
        minimum=min(seen) if seen else None,
        maximum=max(seen) if seen else None,
        distinct=len(set(seen)),
        last=seen[-1] if seen else None,
    )


def _runs(addresses: Iterable[int]) -> list[list[int]]:
    """Maximal runs of consecutive addresses."""
    runs: list[list[int]] = []
    for a in sorted(addresses):
        if runs and runs[-1][-1] == a - 1:
            runs[-1].append(a)
        else:
            runs.append([a])
    return runs
