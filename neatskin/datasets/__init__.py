"""Datasets: parquet schema, crash-safe writer, reader, validation, curation, baselines."""
