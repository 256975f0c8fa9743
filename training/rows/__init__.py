"""The implementations of Table I's reference rows (registered in :mod:`training.references`): the
constant and oracle rows (:mod:`.baselines`), the start-rest estimate (:mod:`.start_rest`), the
sequence-mean oracle (:mod:`.sequence_mean`) and the causal bias filter (:mod:`.bias_filter`, also a
base of the context networks). Each imports only numpy and the dataset's records: no torch."""
