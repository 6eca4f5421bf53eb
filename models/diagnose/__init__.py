"""Reserved for diagnosis (issue 12): replay, residuals, localisation, the named-physics
catalogue. May import every other hmpc.models stage; never controller or tools.
"""
