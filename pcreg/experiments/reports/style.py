"""How each method is drawn in the evaluations' figures: (label, colour, line style)."""

METHOD_STYLE = {
    "plain": ("naive Bayes (plain)", "#444444", "-"),
    "thesis_before": ("thesis: before registration", "#d62728", ":"),
    "thesis_after": ("thesis: after registration", "#ff7f0e", "--"),
    "thesis_after_masked": ("after, border from unwarped frame", "#bcbd22", "-."),
    "thesis_after_cropped": ("after, border left out", "#8c564b", "-."),
    "augmented": ("augmented (registered label prior)", "#1f77b4", "-"),
    "augmented_unregistered": ("augmented, prior not registered", "#17becf", "--"),
    "augmented_temporal": ("augmented, temporal", "#9467bd", "-"),
    "augmented_flow": ("augmented, prior warped by DIS flow", "#e377c2", "--"),
    "propagated": ("warped labels alone", "#2ca02c", ":"),
}
