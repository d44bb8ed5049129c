"""Experiments: run metrics, suites over scenarios x controllers x tunings x seeds, reports."""
