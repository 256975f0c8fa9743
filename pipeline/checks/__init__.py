"""Input checks and repairs: what is wrong with a loaded :class:`~pipeline.types.Sequence`, and how to fix it.

Readers return what a file holds; this package reports every problem as a
:class:`~pipeline.types.Finding` with a stable ``code`` (part of the
``biasgt inspect --json`` contract), a :class:`~pipeline.types.Severity`, a
one-line message that says how to fix it and JSON-serialisable ``details``.
``biasgt convert`` applies only the repairs the user allows
(:func:`~pipeline.checks.repairs.apply_repairs`), re-checks, and refuses while a fatal or an
unrepaired repairable problem remains.

Streams are named ``"imu"``, ``"poses/<stream>"`` and ``"ground_truth"``.

* :mod:`~pipeline.checks.options`: the options, the finding codes, repairs and verdicts;
* :mod:`~pipeline.checks.streams`: a uniform view of each stream;
* :mod:`~pipeline.checks.stream_checks`: the checks of one stream, unit heuristics included;
  :mod:`~pipeline.checks.stamp_unit`: stamps in s, ms or us where nanoseconds are read;
* :mod:`~pipeline.checks.rig`: the rig checks (a pose stream against the IMU over the whole recording: clock
  offset, positions' unit, frame agreement, occlusion placeholders), on :mod:`~pipeline.checks.clock`
  (the whole-overlap clock search), :mod:`~pipeline.checks.rig_fit` (the unit and frame fits) and
  :mod:`~pipeline.checks.rig_signals` (the signals on one grid, compared at every offset at once);
* :mod:`~pipeline.checks.run`: :func:`~pipeline.checks.run.run_checks` (with the cross-stream
  checks), the verdict, the stream summaries;
* :mod:`~pipeline.checks.repairs`: :func:`~pipeline.checks.repairs.apply_repairs`.
"""
