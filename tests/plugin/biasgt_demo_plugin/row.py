"""Half the recovered bias, held as it is: between the zero row and the ground-truth row."""

import numpy as np


def row(items: dict, *, bias_mean: np.ndarray) -> np.ndarray:
    assert bias_mean.shape == (6,)
    return 0.5 * np.asarray(items["bias"], dtype=np.float64)[:, None]
