"""The learning stage's data: the windows stage (:mod:`.windows`, options :mod:`.windows_config`), the
versioned window dataset on disk (:mod:`.dataset`), its typed batches (:mod:`.batch`) and normaliser
(:mod:`.normalizer`), each sequence's whole IMU record beside it (:mod:`.records`), and a simulated
dataset for the context models (:mod:`.sim_context`)."""
