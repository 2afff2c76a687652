"""plod experiments: the command line, batch experiments and benchmarks."""
