"""Noise strengths of a recovery: random walks and pose sigma by maximum evidence (:mod:`.evidence`),
overlapping Allan deviation (:mod:`.allan`), white-noise densities from a recording's rest
(:mod:`.from_data`) and the optimal smoother's error floor for the noise at hand (:mod:`.bounds`).
"""
