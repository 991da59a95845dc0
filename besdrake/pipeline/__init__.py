"""The whole job, stage after stage: imitation from demonstrations now; `learn` (issue 7) later."""
