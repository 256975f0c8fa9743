"""Writing files: atomic output through a temporary sibling (:mod:`.atomic`) and the one JSON/YAML
encoder for numpy, enums, paths and NaN (:mod:`.jsonio`).
"""
