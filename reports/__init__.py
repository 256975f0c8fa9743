"""biasgt reports stage."""
