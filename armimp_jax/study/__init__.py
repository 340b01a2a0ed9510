"""Study tools on top of the general simulator: checked result records and run folders,
statistics, recordings, sweeps, many-host runs and gradient tuning. Files live here and
above; nothing below this layer reads or writes one."""
