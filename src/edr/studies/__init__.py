"""Studies beside the tasks: edr-bench (bench, bench_atari, bench_events), optical flows against
known flows (flows), how stable learning EDR is (edr_stability), what each representation hands
the network (representation_statistics), and the paper's sweeps at tiny scale (tiny_sweeps)."""
