"""The pose stream's clock offset: the coarse correlation and the rig screen (:mod:`.coarse`), then the
refinement on the optimised graph and its spread (:mod:`.offset`).
"""
