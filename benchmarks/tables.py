"""Plain-text tables and number formats shared by the benchmark scripts."""

from __future__ import annotations

__all__ = ["format_table", "si"]


def format_table(headers: list[str], rows: list[list[str]]) -> str:
    """Right-aligned columns under a header and a rule of dashes."""
    widths = [max(len(h), *(len(r[c]) for r in rows)) for c, h in enumerate(headers)]
    line = "  ".join(h.rjust(w) for h, w in zip(headers, widths, strict=True))
    rule = "  ".join("-" * w for w in widths)
    body = ["  ".join(v.rjust(w) for v, w in zip(r, widths, strict=True)) for r in rows]
    return "\n".join([line, rule, *body])


def si(x: float) -> str:
    """A rate with a k / M suffix: 1.23M, 45.6k, 789, 12.3."""
    if x >= 1e6:
        return f"{x / 1e6:.2f}M"
    if x >= 1e4:
        return f"{x / 1e3:.1f}k"
    return f"{x:.1f}" if x < 100 else f"{x:.0f}"
