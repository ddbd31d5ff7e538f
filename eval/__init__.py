"""Evaluator: ADD / ADD-S AUC, calibration error, BOP results and the paper's tables."""
