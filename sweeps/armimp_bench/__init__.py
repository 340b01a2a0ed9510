"""The project's own measurement harness: what the benchmark scripts beside it in ``sweeps/``
measure (speed, convergence, identification and design checks). It is not installed with
``armimp_jax``: the scripts find it beside them, the suite through pytest's ``pythonpath``.
"""
