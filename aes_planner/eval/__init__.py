"""Evaluations on simulated scenes, where ground truth exists at every pose.

* :mod:`aes_planner.eval.search` — ``aes-planner eval search``: suggestion quality against an
  exhaustive oracle and the baselines, gradient-ascent gain, search ablations.
"""
