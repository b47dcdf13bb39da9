"""Inverse kinematics solvers."""
