"""Multiplexed read-out of the capacitor array: the array model and lead patterns."""
