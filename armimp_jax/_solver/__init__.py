"""Integrators of the plant over one control period, and ``Numerics``, which holds one."""
