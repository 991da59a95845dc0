"""The throwing task's ``besdrake learn`` stages (:func:`besdrake.pipeline.learn.learn` runs them; configuration:
``learn.yaml`` beside this package), from demonstrations to a template pool (paper Table 1 and Figure 1):

 1. ``label``      automatic marker labeling (unnamed trajectories -> named markers), gap filling
 2. ``segment``    vMCI segmentation and 1-NN classification: the throw segments
 3. ``imitate``    embodiment mapping and DMP imitation: one plan of the robot per throw
 4. ``refine``     policy search in simulation (CMA-ES on the 49 DMP parameters)
 5. ``transfer``   Transferability Approach with the designed simulation and the lab
 6. ``diagnose``   what the simulation gets wrong, its cause, a refined scenario
 7. ``transfer_refined``  Transferability Approach again, with the refined simulation
 8. ``template``   behaviour template learning (BO-CPS) over the target position
 9. ``pool``       the template pool
10. ``report``     report.md with figures and meshcat replays


The stages live in one module per step of the pipeline: :mod:`.demonstrations` (1-3), :mod:`.refinement` (4),
:mod:`.transfer` (5-7), :mod:`.template` (8, 9) and :mod:`.report` (10).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from besdrake.pipeline.learn import Context
from besdrake.tasks.throwing.learn.demonstrations import stage_imitate, stage_label, stage_segment
from besdrake.tasks.throwing.learn.refinement import refinement_settings, stage_refine
from besdrake.tasks.throwing.learn.report import stage_report
from besdrake.tasks.throwing.learn.template import stage_pool, stage_template, template_reach_settings
from besdrake.tasks.throwing.learn.transfer import diagnosis_design, stage_diagnose, stage_transfer, stage_transfer_refined, transfer_config

__all__ = ["STAGES", "diagnosis_design", "refinement_settings", "template_reach_settings", "transfer_config"]


STAGES: list[tuple[str, Callable[[Context, Path], dict[str, Any]]]] = [
    ("label", stage_label),
    ("segment", stage_segment),
    ("imitate", stage_imitate),
    ("refine", stage_refine),
    ("transfer", stage_transfer),
    ("diagnose", stage_diagnose),
    ("transfer_refined", stage_transfer_refined),
    ("template", stage_template),
    ("pool", stage_pool),
    ("report", stage_report),
]
