"""biasgt reports stage: the per-sequence dataset quality report (self-contained HTML).

Public API (import from the submodules; this package imports nothing heavy itself)::

    from reports.quality import build_quality_report   # (ingest_dir, *, recovery_dir, validation_dir, out_path)
    from reports.allan import allan_deviation, fit_noise_parameters, imu_allan

Command line: ``biasgt report RESULTS_DIR --sequence NAME --out FILE.html``.
"""
