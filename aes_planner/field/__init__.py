"""The 3D aesthetic field (the paper's student) and the ``Scorer`` interface the search uses."""

from aes_planner.field.scorer import ScoreOutput, Scorer, ScorerError, check_poses

__all__ = ["ScoreOutput", "Scorer", "ScorerError", "check_poses"]
