"""Training: the one trainer of every registered network (:mod:`.train`), its run folder and checkpoints
(:mod:`.checkpoint`) and the exponential moving average of the weights (:mod:`.ema`)."""
