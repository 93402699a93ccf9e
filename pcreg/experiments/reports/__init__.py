"""Reports of the evaluations: tables (CSV, Markdown), figures (PNG) and checks, read only from the
results.json document of what :mod:`pcreg.experiments` returns (``Results.to_dict()``), the same document
``pcreg view OUT_DIR`` reads back from disk."""
