"""Motion capture: Qualisys TSV / C3D I/O, marker labeling, preprocessing (a task may ship a synthetic demonstrator
of its own: ``besdrake/tasks/<name>/demonstrator.py``).

* :mod:`~besdrake.mocap.qualisys` -- ``read_recording`` / ``write_recording`` (TSV and C3D, metres in memory);
* :mod:`~besdrake.mocap.labeling` -- :class:`MarkerLabeler` (unnamed trajectories -> named markers);
* :mod:`~besdrake.mocap.gaps` -- gap filling; :mod:`~besdrake.mocap.preprocess` -- back frame, hand pose.
"""

from besdrake.mocap.qualisys import read_recording, read_tsv, write_recording, write_tsv
from besdrake.mocap.recording import MocapFormatError, MocapRecording

__all__ = ["MocapFormatError", "MocapRecording", "read_recording", "read_tsv", "write_recording", "write_tsv"]
