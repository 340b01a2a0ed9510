"""Experiment design through the simulator: the perturbation and the gains (on the bound, by
Monte Carlo, along a reach), the record length a precision needs, the robot's sensitivity, the
Mhat tuner and the one optimisation loop they share."""
