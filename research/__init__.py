"""The project's research, outside the wheel: studies, ablation entries and bundles, and notes.

Run a study from the repository's root, e.g. ``python -m research.studies.generalist --help``.
"""
