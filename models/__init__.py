"""hmpc offline math: ingest, signals, identification, plant and diagnosis.

Nothing here imports ``controller`` or ``tools``; everything is testable without a bus.
"""
