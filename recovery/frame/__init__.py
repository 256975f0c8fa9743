"""The body frame and gravity: the IMU/pose frame agreement check (:mod:`.check`), the estimated
extrinsic against a calibration file's (:mod:`.extrinsic`) and gravity's direction with the level test
(:mod:`.gravity`).
"""
