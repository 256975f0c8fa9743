"""biasgt recovery stage."""
