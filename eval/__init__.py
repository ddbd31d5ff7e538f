"""Evaluator: runs a method over a BOP data set frame by frame (`python -m eval.run`, methods/) and scores
it - ADD / ADD-S AUC, calibration error - into BOP results, the paper's tables and curves and an HTML
report; also the peers that run here (PPF + ICP, marker hand-eye) and the targeting experiment."""
