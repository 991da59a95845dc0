"""Tasks as plug-ins: what a skill adds to the platform (scene, outcome, reward, features, lab measurements).

One folder per task (``throwing``, ``pick_and_place``); the stage folders know no task.
"""
