"""Imitation: dynamical movement primitives (joint space and Cartesian)."""
