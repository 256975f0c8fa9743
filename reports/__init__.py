"""biasgt reports stage: the per-sequence dataset quality report (self-contained HTML).

Public API (import from the submodules; this package imports nothing heavy itself)::

    from reports.quality import build_quality_report   # (ingest_dir, *, recovery_dir, validation_dir, out_path)
    from reports.dataset import build_dataset_report     # (results_dir, out_path=None): results/report/index.html

Command line: ``biasgt report RESULTS_DIR --sequence NAME --out FILE.html``; ``biasgt report RESULTS_DIR``
writes the dataset page. The Allan deviation it draws is :mod:`recovery.noise.allan`.
"""
