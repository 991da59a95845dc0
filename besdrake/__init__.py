"""besdrake: the BesMan learning platform on Drake.

Stages, in the order data flows through them:
``mocap`` -> ``segmentation`` -> ``imitation`` -> ``embodiment`` -> ``sim`` -> ``search``
-> ``transfer`` -> ``diagnosis``.
"""

__version__ = "0.1.0"
