"""The throwing task: a ball thrown from a scoop onto a target on the floor (the BesMan experiments)."""
