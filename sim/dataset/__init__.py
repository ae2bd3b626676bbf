"""The benchmark dataset: generation, records on disk, verification and loading."""
