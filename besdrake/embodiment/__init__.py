"""Embodiment mapping: record mapping, synchronization frame, spatial and temporal scaling."""
