"""Sim-to-real: the lab interface, measured-data logs, the Transferability Approach."""
