"""Diagnosis (issue 12): replay and residuals, localisation, the named-physics catalogue, the
HTML report. May import every other hmpc.models stage; never controller or tools.
"""
