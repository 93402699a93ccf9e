"""Per-pixel classification: features, naive Bayes, metrics, and fusion with a warped label prior."""
