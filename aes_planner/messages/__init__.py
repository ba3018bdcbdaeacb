"""Typed messages exchanged between the parts of the planner.

Today: :class:`PosedFrame`, the record every camera (real, simulated, or read from a dataset
folder) produces. The versioned binary encoding, size caps and the other messages
(``ViewSuggestion``, ``GimbalCommand``, ``GimbalState``, ``Diagnostics``) join it here.
"""

from aes_planner.messages.posed_frame import MessageError, PosedFrame

__all__ = ["MessageError", "PosedFrame"]
