"""Simulation: COMPI with scoop as a Drake Diagram, physical effects, rollouts and executors."""
