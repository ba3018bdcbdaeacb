"""Evaluations on simulated scenes, where ground truth exists at every pose.

* :mod:`aes_planner.eval.field` — ``aes-planner eval field``: novel-view aesthetic prediction
  (Table 1 and the view-conditioning ablation): rgb, splat, field_nocond, field.
* :mod:`aes_planner.eval.search` — ``aes-planner eval search``: suggestion quality against an
  exhaustive oracle and the baselines, gradient-ascent gain, search ablations.
* :mod:`aes_planner.eval.closed_loop` — ``aes-planner demo``'s scoring of a finished closed loop
  against the same oracle, normalised the same way.
"""
