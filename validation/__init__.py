"""Validation stage: 1-s integration error (PRMSE m, ROE deg) of a bias against reference states, and a verdict."""
