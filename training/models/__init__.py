"""The bias models: the networks of the registered methods (:mod:`.layers`, :mod:`.rnn`, :mod:`.unet`;
registered in :mod:`training.networks`), the one model that wraps any of them (:mod:`.bias_model`),
the diffusion schedule and samplers (:mod:`.scheduler`) and the samplers' x0 clip (:mod:`.clip`).

This ``__init__`` imports nothing: naming a module here costs no torch until it is imported."""
