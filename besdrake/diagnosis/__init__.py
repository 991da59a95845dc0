"""Diagnosis: what the simulation gets wrong, its cause, the refined model and the gain."""
