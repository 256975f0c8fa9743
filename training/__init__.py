"""The learning stage: window dataset, bias models, training, evaluation, Table I, prediction and export.

By role:

* :mod:`training.config`: every option of the stage (models, training, the workflow's ``training:``
  and ``evaluation:`` sections), defined once.
* :mod:`training.networks` and :mod:`training.references`: the two registries (the learned methods
  and Table I's reference rows); they import nothing of the package, so that listing names costs no
  torch.
* :mod:`training.data`: the window dataset on disk, its batches and normaliser, the sequence records
  and the windows stage that cuts them.
* :mod:`training.models`: the networks, the model that wraps them, the diffusion schedule and its clip.
* :mod:`training.rows`: the reference rows' implementations (and the bias filter they share).
* :mod:`training.context`: the networks that read the record before their window.
* :mod:`training.fit`: the trainer, its checkpoints and the weights' moving average.
* :mod:`training.evaluation`: the test protocol, its outputs and Table I.
* :mod:`training.deploy`: prediction on new recordings, export, speed probes.
"""
