"""Simulation: the plant of ``core`` with the laws of ``control`` assembled.

Simulators and batch kernels, the node steppers, the corner and controller configuration.
"""
