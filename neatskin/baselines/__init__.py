"""Regression baselines: the paper LM network, scikit-learn models, evaluation and report."""
