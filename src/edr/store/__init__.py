"""The results store: run folders and what a run does when it meets one again (folders),
what makes two runs the same (identity), run records, checkpoints, durable writes (atomic),
and the files Hydra writes for a job, once its folder is checked (job_files)."""
