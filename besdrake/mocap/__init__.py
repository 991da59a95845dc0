"""Motion capture: Qualisys TSV / C3D I/O, the synthetic demonstrator, marker labeling, preprocessing.

* :mod:`~besdrake.mocap.qualisys` -- ``read_recording`` / ``write_recording`` (TSV and C3D, metres in memory);
* :mod:`~besdrake.mocap.synthetic` -- :class:`SyntheticDemonstrator`, overhand throws with ground truth;
* :mod:`~besdrake.mocap.labeling` -- :class:`MarkerLabeler` (unnamed trajectories -> named markers);
* :mod:`~besdrake.mocap.gaps` -- gap filling; :mod:`~besdrake.mocap.preprocess` -- back frame, hand pose.
"""

from besdrake.mocap.qualisys import read_recording, read_tsv, write_recording, write_tsv
from besdrake.mocap.recording import MocapFormatError, MocapRecording

__all__ = ["MocapFormatError", "MocapRecording", "read_recording", "read_tsv", "write_recording", "write_tsv"]
