"""What a results directory keeps beside its runs: the MLflow mirror, fleet checkpoints, leftovers, past renames."""
