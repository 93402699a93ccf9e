"""Reports of the evaluations: tables (CSV, Markdown), figures (PNG) and checks, read only from the
results that :mod:`pcreg.experiments` returns (what results.json holds)."""
