"""One recovery window's factor graph and its solve: midpoint preintegration at keyframes off the IMU
stamps (:mod:`.preintegration`), the window's records (:mod:`.window`), initial states (:mod:`.initial`),
factors (:mod:`.factors`), keyframes in pose gaps (:mod:`.gaps`), Gauss-Newton solve and marginals
(:mod:`.graph`), time-correlated pose error states (:mod:`.pose_error`), pose fusion into keyframes
(:mod:`.fusion`), overlapping segments and stitching (:mod:`.segments`), NumPy rotations
(:mod:`.rotations`) and the calibration's uncertainty in the bias sigmas (:mod:`.calibration_uncertainty`).
"""
