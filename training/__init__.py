"""biasgt training stage."""
