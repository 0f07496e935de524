"""The results store: run folders and what a run does when it meets one again (folders),
what makes two runs the same (identity), run records, checkpoints, durable writes (atomic),
and rebuilding a run's parts from its record (rebuild)."""
