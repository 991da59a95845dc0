"""The throwing task's part of the diagnosis: what a throw shows (:mod:`.observables`), the designed diagnosis throws
and tilt probes (:mod:`.design`) and the model the engine reads them through (:mod:`.model`,
:meth:`besdrake.tasks.throwing.task.ThrowingTask.diagnosis_model`)."""
