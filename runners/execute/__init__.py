"""Executing a sweep's work in a worker: one job (a run, or a fleet trained together), each run recorded last."""
