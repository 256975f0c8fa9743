"""biasgt interpolation stage."""
