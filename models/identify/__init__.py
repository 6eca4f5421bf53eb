"""Identification: the report's steering map (eqs. 2-7) and zone accelerator models (eq. 8),
fast orthogonal search and interval statistics. Imports hmpc.models.logs, plant and params.
"""
