"""Scoring of strand files against ground truth (reads strand files only; never imports ``fit``)."""

from vid2haircut.evaluate.metrics import THRESHOLDS, evaluate_files, evaluate_strands

__all__ = ["THRESHOLDS", "evaluate_files", "evaluate_strands"]
