"""Cross-validation of a recovered bias by time blocks: recover on some blocks and judge on the others
(:mod:`.blocks`), and the errors on the windows each bias was held out of (:mod:`.heldout`).
"""
