"""What the benchmark scripts in ``sweeps/`` measure (speed, convergence, identification and
design checks), above every other floor: the scripts parse their options, set XLA up and
call these modules. Nothing else in the package imports them.
"""
