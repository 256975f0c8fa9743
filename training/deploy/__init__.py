"""A trained model used outside the workflow: the bias of a new recording (:mod:`.predict`), the model
and its sampler as one TorchScript or ONNX graph (:mod:`.export`), and speed probes (:mod:`.speed`)."""
