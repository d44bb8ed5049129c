"""Counts in what the toolkit prints and writes: "1 pair", "2 pairs" (a count with a hard
plural said "n/a: 1 pairs < 6", "1 worlds", "1 runs")."""

from __future__ import annotations


def noun(n: int, word: str, plural: str | None = None) -> str:
    """``word`` for ``n`` == 1, else its plural (``word + "s"`` unless given)."""
    return word if n == 1 else (plural or f"{word}s")


def count(n: int, word: str, plural: str | None = None) -> str:
    """``n`` and its noun: ``count(1, "pair")`` -> ``"1 pair"``, ``count(0, "pair")`` ->
    ``"0 pairs"``."""
    return f"{n} {noun(n, word, plural)}"
