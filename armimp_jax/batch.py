"""Batches of trials over devices: padding, sharding, grouping, and their outcomes.

A namespace of the public face: ``import armimp_jax as aj; aj.batch.NAME`` (docs/design.md,
"The public names")."""

from __future__ import annotations

from ._batch import MAX_PER_DEVICE as MAX_PER_DEVICE
from ._batch import assess as assess
from ._batch import assess_batch as assess_batch
from ._batch import batch_groups as batch_groups
from ._batch import check_numerics as check_numerics
from ._batch import default_lanes as default_lanes
from ._batch import make_mesh as make_mesh
from ._batch import padded_batch_size as padded_batch_size
from ._batch import shard_batch as shard_batch
from ._simulate import stack_trials as stack_trials

__all__ = [
    "MAX_PER_DEVICE",
    "assess",
    "assess_batch",
    "batch_groups",
    "check_numerics",
    "default_lanes",
    "make_mesh",
    "padded_batch_size",
    "shard_batch",
    "stack_trials",
]
