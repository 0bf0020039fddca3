"""The memory budget: big arrays are sized against it before they are allocated.

Every place that allocates an array whose size the user controls (a resampled map, a
TERCOM search window, an INS-error-driven search area, the beams of a multibeam, the
suitability layers) calls :func:`check_allocation` first, with its own estimate of the
bytes it is about to use. What would not fit is refused with a :class:`MemoryBudgetError`
that gives the estimate and the limit, instead of letting the kernel kill the machine.

The budget is, in order of precedence:

1. the environment variable ``GEOFIX_MEMORY_BUDGET`` (the CLI's ``--memory-budget``
   sets it, so worker processes inherit it): a size such as ``2GiB``, ``500MB``,
   ``1.5e9`` (bytes) or a share of the machine's RAM such as ``25%``;
2. otherwise :data:`DEFAULT_FRACTION` of the machine's physical RAM.
"""

from __future__ import annotations

import os
import re

from geofix.errors import MemoryBudgetError

ENV_VAR = "GEOFIX_MEMORY_BUDGET"
#: Share of the physical RAM allowed by default (a single campaign worker or command).
DEFAULT_FRACTION = 0.5
_FALLBACK_RAM = 8 * 2**30
_UNITS = {
    "": 1,
    "b": 1,
    "k": 1e3,
    "kb": 1e3,
    "m": 1e6,
    "mb": 1e6,
    "g": 1e9,
    "gb": 1e9,
    "t": 1e12,
    "tb": 1e12,
    "kib": 2**10,
    "mib": 2**20,
    "gib": 2**30,
    "tib": 2**40,
}
_SIZE = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:e[+-]?[0-9]+)?)\s*([a-z%]*)\s*$", re.IGNORECASE)


def _physical_ram_bytes() -> int:
    """The machine's physical RAM, bytes (8 GiB when the system does not say)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, ValueError, OSError):
        return _FALLBACK_RAM


def parse_size(text: str) -> int:
    """Bytes from ``"2GiB"``, ``"500MB"``, ``"1.5e9"`` or ``"25%"`` (of physical RAM).

    Raises
    ------
    MemoryBudgetError
        The text is not a positive, finite size.
    """
    match = _SIZE.match(str(text))
    unit = match.group(2).lower() if match else None
    if match is None or (unit != "%" and unit not in _UNITS):
        raise MemoryBudgetError(
            f"memory budget {text!r} is not a size (examples: 2GiB, 500MB, 1.5e9, 25%)"
        )
    value = float(match.group(1))
    size = value / 100 * _physical_ram_bytes() if unit == "%" else value * _UNITS[unit]
    if not size >= 1:
        raise MemoryBudgetError(f"memory budget {text!r} must be positive")
    if not size < float("inf"):
        raise MemoryBudgetError(f"memory budget {text!r} is not a finite size")
    return int(size)


def memory_budget_bytes() -> int:
    """The current budget, bytes (``GEOFIX_MEMORY_BUDGET`` or a share of the RAM)."""
    text = os.environ.get(ENV_VAR, "").strip()
    if text:
        return parse_size(text)
    return int(DEFAULT_FRACTION * _physical_ram_bytes())


def format_bytes(n: float) -> str:
    """``n`` bytes as ``"53.8 TiB"`` (binary units); ``"inf"`` for an unbounded size."""
    if not n < float("inf"):
        return "an unbounded size"
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if abs(n) < 1024 or unit == "PiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.3g} EiB"  # pragma: no cover - loop always returns


def check_allocation(nbytes: float, what: str) -> None:
    """Refuse an allocation of ``nbytes`` that would exceed the memory budget.

    Parameters
    ----------
    nbytes : float
        Estimated peak bytes of the arrays about to be allocated (may be ``inf`` or huge:
        it is compared as a float, never allocated).
    what : str
        What would be allocated and why, for the message (e.g.
        ``"map at resample_m 0.5 (40001 x 40001 cells)"``).

    Raises
    ------
    MemoryBudgetError
        ``"<what> would need 53.8 TiB; memory budget 11.7 GiB (set GEOFIX_MEMORY_BUDGET
        or --memory-budget)"``.
    """
    budget = memory_budget_bytes()
    nbytes = float(nbytes)
    if nbytes != nbytes or nbytes > budget:
        raise MemoryBudgetError(
            f"{what} would need {format_bytes(nbytes)}; memory budget "
            f"{format_bytes(budget)} (set {ENV_VAR} or --memory-budget)"
        )


def cells_bytes(*dims: float, copies: float = 1.0, itemsize: int = 8) -> float:
    """Bytes of ``copies`` float arrays of shape ``dims`` (as a float: never overflows).

    Parameters
    ----------
    *dims : float
        The array's shape (a negative size counts 0).
    copies : float
        Number of arrays of that shape.
    itemsize : int
        Bytes per element.

    Returns
    -------
    float
        ``copies * itemsize * prod(dims)``, bytes.
    """
    total = float(copies) * itemsize
    for d in dims:
        total *= max(float(d), 0.0)
    return total
