"""Synthetic top-down scenes with known geometry: a wooden board, food on it, the true outline."""
