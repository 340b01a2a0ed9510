"""How a study runs: the one engine (``engine.run``), run folders and their lock, checked records
and strict-JSON writes, seeds, many processes, the console and what the scripts share (``cli``)."""
