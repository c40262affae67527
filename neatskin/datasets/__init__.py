"""Datasets: parquet schema, crash-safe writer, reader, validation, curation, plots.

schema (columns and `neatskin.` metadata), durable (atomic fsync'd writes), paths (folder layout),
writer (CampaignWriter: durable parts, one press each on the real rig, batched in a dry run; finalize), manifest (manifest.json), reader
(read_presses, feature_matrix), validate (validate_dataset), curate (describe, merge, split, export),
plots (sensitivity and press maps), cli
(`neatskin dataset ...`). Imports only the ground floor (layout, errors, tomlfile).
"""
