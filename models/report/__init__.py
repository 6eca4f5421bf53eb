"""Figures (and later HTML reports) of recordings and fits, each on its own Agg canvas (no
backend set, no pyplot: ``figure.new_figure``); imports the other hmpc.models stages only.
"""
