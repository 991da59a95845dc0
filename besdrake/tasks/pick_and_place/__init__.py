"""The pick-and-place task: a box picked from a shelf and placed on a table by a 7-DOF arm with a gripper.

Demonstrations come from the real recordings (``demonstrations``: Qualisys TSV -> grasp
demonstrations in the task frame, with the shipped 1-NN movement classifier ``classifier.npz``).
"""
