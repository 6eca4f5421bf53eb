"""Figures (and later HTML reports) of recordings and fits. matplotlib is imported lazily,
with the Agg backend chosen by the caller; imports the other hmpc.models stages only.
"""
