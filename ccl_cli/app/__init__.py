"""The application layer: stages, runs, evaluation, batches, provenance."""
