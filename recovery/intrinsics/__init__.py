"""IMU intrinsics around the bias recovery: the estimate of scale, misalignment and g-sensitivity
(:mod:`.estimate`), the accelerometer's rotation against the calibration (:mod:`.frame`), what
``recovery.json`` says of them (:mod:`.report`) and the gyro's agreement with a reference attitude
(:mod:`.gyro_consistency`).
"""
