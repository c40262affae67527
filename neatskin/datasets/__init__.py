"""Datasets: parquet schema, crash-safe writer, reader, validation, curation, baselines.

schema (columns and `neatskin.` metadata), durable (atomic fsync'd writes), paths (folder layout),
writer (CampaignWriter: one durable part per press, finalize), manifest (manifest.json), reader
(read_presses, feature_matrix), validate (validate_dataset), curate (describe, merge, split, export),
plots (sensitivity and press maps), synthetic (stand-in rows for tests and benchmarks), cli
(`neatskin dataset ...`), baselines (regression models and their report). Nothing here imports neatskin.rig.
"""
