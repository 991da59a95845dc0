"""The pick-and-place task's diagnosis: its trials' observables (:mod:`.model`) and designed experiments
(:mod:`.design`)."""
