"""Experiments: the `Experiment` schema, the `reproduce` pipeline, evaluations of registered methods and reruns."""
