"""Embodiment mapping: record mapping, synchronization frame, spatial and temporal scaling.

Data flow for one demonstrated movement (paper sections 2.3.2 and 3.1.4):

* :func:`record_mapping.hand_trajectory` -- hand poses of a segment in the demonstrator's back frame;
* :func:`sync_frame.solve_sync_frame` -- where the robot's base sits relative to that frame (one
  SNOPT program over the frame and all joint configurations);
* :func:`ik.ik_trajectory` -- joint positions at the recording's rate (Drake InverseKinematics);
* :mod:`scaling` -- uniform temporal scaling to the joint limits, Toppra's time-optimal bound;
* :class:`mapping.EmbodimentMapping` -- all of the above plus the DMP fit: an
  :class:`mapping.ImitatedMovement` with the 49 parameters policy search refines.
"""

from besdrake.embodiment.mapping import EmbodimentMapping, ImitatedMovement, ImitationError, ImitationOptions
from besdrake.embodiment.record_mapping import HandTrajectory, RecordMappingError, hand_trajectory

__all__ = [
    "EmbodimentMapping",
    "HandTrajectory",
    "ImitatedMovement",
    "ImitationError",
    "ImitationOptions",
    "RecordMappingError",
    "hand_trajectory",
]
