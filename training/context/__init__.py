"""The networks that read what came before their window in the sequence's record (registered in
:mod:`training.networks`, trained and evaluated like every other network): the context features and
the regressed residual (:mod:`.model`), and the residual drawn by a diffusion model (:mod:`.diffusion`)."""
