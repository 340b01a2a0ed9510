"""Experiment design's configs and files, its check by Monte Carlo and report, and the tuner."""
