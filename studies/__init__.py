"""Studies built on the diagrams: running and comparing the smoothing methods
(:mod:`~telesmooth.studies.comparison`: the methods' runs and the docs/method.md §6 metrics),
the LASA experiment's task grid and runner (:mod:`~telesmooth.studies.experiment`), and the
verdicts on the claims from its records (:mod:`~telesmooth.studies.claims`).
"""
